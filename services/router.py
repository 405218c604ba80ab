"""`railswitch router`: a Zenoh router from eclipse-zenoh, for machines without `zenohd`."""
from __future__ import annotations

import logging
import threading

from services.bus import BusOptions, open_session

log = logging.getLogger("railswitch.router")


def run_router(options: BusOptions, *, stop: threading.Event) -> None:
    """Route until stop is set."""
    session = open_session(options, retry=False)
    try:
        log.info("router %s listening on %s", session.zid(), ", ".join(options.listen) or "the config file's endpoints")
        stop.wait()
    finally:
        session.close()
