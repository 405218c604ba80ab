"""Where a diagnoser keeps each switch's commissioned baseline, so that a restarted one resumes it.

One JSON document per model and switch: `<directory>/<model>/<switch_id>.json`, written atomically.
The directory is `--state DIR`, else `$RAILSWITCH_STATE`, else `$XDG_STATE_HOME/railswitch/baselines`
(`~/.local/state/railswitch/baselines`). A baseline belongs to the reduced model that learnt it.
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from pydantic import ConfigDict, TypeAdapter

from railswitch.schemas import check_switch_id
from railswitch.services.adapters.user_directories import user_directory

log = logging.getLogger("railswitch.baselines")
# pydantic's JSON encoder, non-finite numbers as json.dumps writes them (NaN, Infinity: json.loads reads them back);
# several times faster than json.dumps at a switch's state, written after every throw
_STATE_JSON = TypeAdapter(dict, config=ConfigDict(ser_json_inf_nan="constants"))


def default_directory() -> Path:
    return user_directory("RAILSWITCH_STATE", "XDG_STATE_HOME", (".local", "state"), "baselines")


class BaselineStore:
    """The baselines of one reduced model's switches on disk."""

    def __init__(self, model: str, directory: str | Path | None = None):
        self.directory = Path(directory) if directory is not None else default_directory()
        self.folder = self.directory / model
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, switch_id: str) -> Path:
        return self.folder / f"{check_switch_id(switch_id)}.json"

    def load(self, switch_id: str) -> dict | None:
        """The switch's stored state, or None (never commissioned here, or an unreadable file: said once)."""
        path = self._path(switch_id)
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError) as error:
            log.warning("%s: cannot read its baseline %s (%s); commissioning it afresh", switch_id, path, error)
            return None

    def save(self, switch_id: str, state: dict) -> None:
        path = self._path(switch_id)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_bytes(_STATE_JSON.dump_json(state))
        os.replace(partial, path)

    def known(self, switch_id: str) -> bool:
        return self._path(switch_id).is_file()
