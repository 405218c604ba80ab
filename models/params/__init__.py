"""Shipped weights of the reduced rail representations (plain JSON, made by `railswitch train`)."""
from __future__ import annotations

import json
from importlib import resources

import numpy as np

from models.rail_models import REPRESENTATIONS, Representation
from models.reference import DIRECTIONS


def weights_document(representation: Representation, weights: np.ndarray, training: dict) -> dict:
    """The JSON document of one representation: named weights in physical units plus provenance."""
    named = representation.unflatten(np.asarray(weights, dtype=float))
    return {"representation": representation.name, "equations": list(representation.equations),
            "weights": {k: np.asarray(v).tolist() for k, v in named.items()}, "training": training}


NEUTRAL_PORT = {direction: {"gain": 1.0, "offset_s_m": 0.0} for direction in DIRECTIONS}


def _document(name: str) -> dict:
    if name not in REPRESENTATIONS:
        raise ValueError(f"unknown rail model {name!r}; accepted: {', '.join(REPRESENTATIONS)}")
    return json.loads(resources.files(__name__).joinpath(f"{name}.json").read_text())


def bearing_port(name: str) -> dict[str, dict[str, float]]:
    """The calibrated bearing-fault port of a shipped model, per direction of motion (neutral when
    never calibrated; a port stored as one gain and offset serves both directions)."""
    port = _document(name).get("bearing_port", NEUTRAL_PORT)
    return {d: {key: float(port.get(d, port)[key]) for key in ("gain", "offset_s_m")} for d in DIRECTIONS}


def validation(name: str) -> dict:
    """The quick validation stored with a model's weights (models/validation.py), empty when never made."""
    return _document(name).get("validation", {})


def load(name: str) -> tuple[Representation, np.ndarray, dict]:
    """Representation, flat weights and training provenance of a shipped model."""
    document = _document(name)
    representation = REPRESENTATIONS[name]
    weights = representation.flatten({k: np.array(v) for k, v in document["weights"].items()})
    return representation, weights, document["training"]
