"""A throw sent as one record is diagnosed exactly as the same throw streamed as samples and events
(services/core/records.py into services/core/fleet_diagnoser.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from railswitch.schemas import Diagnosis, ThrowRecord, encode
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.core.records import record_of_throw, throw_of_record
from railswitch.services.core.throw_cutter import cut_throws

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


def verdict(diagnosis: Diagnosis) -> dict:
    """Everything a diagnosis says about its throw (not which switch, nor how long it took)."""
    return diagnosis.model_dump(exclude={"switch_id", "latency_ms"})


@pytest.mark.parametrize("scenario", ["left_bolt", "missing_bearing"])
def test_a_throw_as_a_record_gets_the_diagnosis_of_the_same_throw_as_samples(diagnoser, scenario):
    diagnoser.switches.clear()
    streamed = [t for t in cut_throws(load_recording(RECORDINGS / f"{scenario}.mcap").messages) if t.complete]
    for throw in streamed:  # one switch streamed, its twin recorded: each with its own commissioning
        record = record_of_throw(throw).model_copy(update={"switch_id": f"{scenario}-recorded"})
        on_the_bus = ThrowRecord.model_validate_json(encode(record))
        by_samples = diagnoser.diagnose(throw).diagnosis
        by_record = diagnoser.diagnose(throw_of_record(on_the_bus)).diagnosis
        assert by_samples.hypotheses  # fitted, not refused: the comparison has numbers in it
        assert verdict(by_record) == verdict(by_samples)  # bit for bit: the same numbers reach the estimator


def test_a_current_only_record_is_diagnosed_from_the_current_alone(diagnoser):
    throw = next(t for t in cut_throws(load_recording(RECORDINGS / "nominal.mcap").messages) if t.complete)
    record = record_of_throw(throw).model_copy(update={"switch_id": "current-only", "angle_rad": None,
                                                        "velocity_rad_s": None})
    diagnosis = diagnoser.diagnose(throw_of_record(ThrowRecord.model_validate_json(encode(record)))).diagnosis
    assert diagnosis.signals in ([], ["current_a"])  # [] : decided unknown before any fit
    assert diagnosis.decision != "unknown" or diagnosis.reason
