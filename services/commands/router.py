"""`railswitch router`: a Zenoh router from eclipse-zenoh, for machines without `zenohd`."""
from __future__ import annotations

import argparse
import logging
import threading
from dataclasses import replace

from railswitch.schemas import DEFAULT_ENDPOINT
from railswitch.services.adapters.zenoh_bus import BusOptions, open_session
from railswitch.services.commands.options import add_service_arguments, run_service

log = logging.getLogger("railswitch.router")


def run_router(options: BusOptions, *, stop: threading.Event) -> None:
    """Route until stop is set."""
    session = open_session(options, retry=False)
    try:
        log.info("router %s listening on %s", session.zid(), ", ".join(options.listen) or "the config file's endpoints")
        stop.wait()
    finally:
        session.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_service_arguments(parser)


def run(args: argparse.Namespace) -> int:
    def serve(options: BusOptions, stop: threading.Event) -> None:
        if not options.listen and not options.config_file:
            options = replace(options, listen=(DEFAULT_ENDPOINT,))
        run_router(replace(options, mode="router"), stop=stop)
    return run_service(serve, args)
