"""Where the reduced models' parameters live: a user directory first, then the ones shipped with the package.

Each rail model is one plain JSON document (`<name>.json`): named weights in physical units,
training provenance, the calibrated bearing port and a quick validation. `railswitch train`
and `railswitch calibrate` write to the user directory, `$RAILSWITCH_MODELS` or else
`$XDG_DATA_HOME/railswitch/models` (`~/.local/share/railswitch/models`), and a document
there is loaded instead of the shipped one; replacing the shipped weights inside the
installed package is an explicit act (`--replace-shipped`).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from railswitch.models.reduced.rail_models import REPRESENTATIONS, Representation
from railswitch.models.reduced.hybrid import BearingPort, NEUTRAL_PORT
from railswitch.models.plant.reference import DIRECTIONS
from railswitch.services.adapters.user_directories import user_directory

SHIPPED_DIR = Path(str(resources.files("railswitch.models").joinpath("params")))


def user_dir() -> Path:
    """The directory of the user's own trained or calibrated models (it need not exist)."""
    return user_directory("RAILSWITCH_MODELS", "XDG_DATA_HOME", (".local", "share"), "models")


def check_name(name: str) -> str:
    if name not in REPRESENTATIONS:
        raise ValueError(f"unknown rail model {name!r}; accepted: {', '.join(REPRESENTATIONS)}")
    return name


def document_path(name: str) -> Path:
    """The document a diagnosis loads: the user's if there is one, else the shipped one."""
    user = user_dir() / f"{check_name(name)}.json"
    return user if user.is_file() else SHIPPED_DIR / f"{name}.json"


@dataclass(frozen=True)
class StoredModel:
    """One rail model's document, read."""

    representation: Representation
    weights: np.ndarray
    training: dict
    bearing_port: BearingPort
    validation: dict  # the quick validation (models/reduced/validation.py); empty when never made
    healthy_gains: dict  # per direction and mode: what a fault mode's fit gains on healthy population throws
    error_model: dict  # {"absolute": {...}, "relative": {...}}: the model's error on each fault parameter
    model_weight: float  # healthy throws' nominal MSE over effective samples (the priors' weight)
    path: Path
    healthy_check: dict = field(default_factory=dict)  # false alarms on held-out healthy switches; empty: never checked

    @property
    def shipped(self) -> bool:
        return self.path.parent == SHIPPED_DIR


def load(name: str) -> StoredModel:
    path = document_path(name)
    document = json.loads(path.read_text())
    representation = REPRESENTATIONS[name]
    weights = representation.flatten({k: np.array(v) for k, v in document["weights"].items()})
    port = document.get("bearing_port", NEUTRAL_PORT)  # one gain and offset may serve both directions
    bearing = {d: {key: float(port.get(d, port)[key]) for key in ("gain", "offset_s_m")} for d in DIRECTIONS}
    calibration = document.get("calibration", {})
    return StoredModel(representation, weights, document["training"], bearing, document.get("validation", {}),
                       calibration.get("healthy_gains", {}), calibration.get("error_model", {}),
                       float(calibration.get("model_weight", 0.0)), path, calibration.get("healthy_check", {}))


def weights_document(representation: Representation, weights: np.ndarray, training: dict) -> dict:
    """The JSON document of one representation: named weights in physical units plus provenance."""
    named = representation.unflatten(np.asarray(weights, dtype=float))
    return {"representation": representation.name, "equations": list(representation.equations),
            "weights": {k: np.asarray(v).tolist() for k, v in named.items()}, "training": training}


def read_document(name: str) -> dict:
    return json.loads(document_path(name).read_text())


def save(name: str, document: dict, *, out_dir: str | Path | None = None, replace_shipped: bool = False) -> Path:
    """Write a model's document to `out_dir`, the user directory (default) or, asked for, over the shipped one."""
    if replace_shipped:
        target = SHIPPED_DIR
    elif out_dir is not None:
        target = Path(out_dir)
        if not target.is_dir():
            raise OSError(f"{target} is not a directory")
    else:
        target = user_dir()
        target.mkdir(parents=True, exist_ok=True)
    path = target / f"{check_name(name)}.json"
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(document, indent=1) + "\n")
    os.replace(partial, path)  # a reader never sees half a document
    return path
