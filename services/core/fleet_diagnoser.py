"""The diagnoser's core, shared by `railswitch diagnose` (offline) and the live diagnoser.

Turns cut throws into `Diagnosis` messages: one SwitchDiagnoser per switch, one
estimator per representation, sample rate and throw length, built once per process.
"""
from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from railswitch.models.estimation import Measurement, ThrowEstimator
from railswitch.models.isolation import OTHER_DIRECTION, ThrowVerdict, commissioning_gains
from railswitch.models.plant import Plant
from railswitch.models.reduced import BearingPort, ReducedParams, ReducedSwitch, port_pairs
from railswitch.models.reference import DIRECTIONS, Reference
from railswitch.models.switch import SwitchSimulation
from railswitch.models.switch_diagnosis import CLOSED_START_M, SwitchDiagnoser, ThrowInput
from railswitch.schemas import RAIL_MODELS, Diagnosis, Hypothesis, Message
from railswitch.services.adapters import model_store
from railswitch.services.adapters.compiled import MachineCode
from railswitch.services.core.switch_messages import switch_messages
from railswitch.services.core.throw_cutter import CutThrow, ThrowCutter

DIAGNOSIS_SUBSTEPS = 2  # integration steps per sample: halves the model error of one step, at twice the cost


@dataclass(frozen=True)
class DiagnosedThrow:
    """A throw, its Diagnosis message and (when it was fitted) the verdict with every estimate."""

    throw: CutThrow
    diagnosis: Diagnosis
    verdict: ThrowVerdict | None


def healthy_plant_throws(rate_hz: float, samples: int) -> list[Measurement]:
    """A healthy, noise-free plant throw each way, as measurements (commissioning on the nominal plant)."""
    plant = Plant()
    switch = SwitchSimulation(plant, rate_hz=rate_hz)
    out, rail = [], CLOSED_START_M["left_to_right"]
    for _ in DIRECTIONS:
        angle_at_start = plant.signals_at(switch.state)["angle_rad"]  # exact: the plant's own state
        throw = switch.throw()
        out.append(Measurement(throw.direction, throw.reference, throw.samples.signals[:samples], angle_at_start, rail))
        rail = CLOSED_START_M[OTHER_DIRECTION[throw.direction]]
    return out


@dataclass
class Diagnoser:
    """Diagnoses throws of any number of switches with one reduced model."""

    model: str = "poly"
    compiled: bool = True
    switches: dict[str, SwitchDiagnoser] = field(default_factory=dict)
    port: BearingPort | None = None  # the bearing port per direction; None: the stored model's

    def __post_init__(self) -> None:
        if self.model not in RAIL_MODELS:
            raise ValueError(f"unknown model {self.model!r}; accepted: {', '.join(RAIL_MODELS)}")
        self._estimator = lru_cache(maxsize=8)(self._build_estimator)

    def _build_estimator(self, rate_hz: float, samples: int) -> tuple[ThrowEstimator, dict]:
        """The estimator for throws of `samples` samples at `rate_hz`, commissioned on the healthy plant;
        compiled to machine code once per machine (services/adapters/compiled.py)."""
        stored = model_store.load(self.model)
        params = ReducedParams(substeps=DIAGNOSIS_SUBSTEPS, bearing_port=port_pairs(self.port or stored.bearing_port))
        reduced = ReducedSwitch(stored.representation, stored.weights, params, rate_hz=rate_hz)
        estimator = ThrowEstimator(reduced, samples, MachineCode() if self.compiled else None)
        return estimator, commissioning_gains(estimator, healthy_plant_throws(rate_hz, samples))

    def warm_up(self, rate_hz: float = 50.0, samples: int = 350) -> None:
        """Build (and compile) the estimator for standard throws before the first one arrives."""
        self._estimator(rate_hz, samples)

    def diagnose(self, throw: CutThrow) -> DiagnosedThrow:
        """The Diagnosis of one throw; latency_ms is this call's wall time."""
        start = time.perf_counter()
        switch = self.switches.setdefault(throw.switch_id, SwitchDiagnoser(self._estimator))
        decision, reason, verdict = switch.diagnose(throw_input(throw))
        hypotheses, joint = [], None
        if verdict is not None:
            for mode, estimate in verdict.estimates.items():
                hypothesis = Hypothesis(mode=mode, params=estimate.params, std=estimate.std, mse=estimate.mse)
                if mode == "joint":
                    joint = hypothesis
                else:
                    hypotheses.append(hypothesis)
        end_ns = throw.end.t_ns if throw.end is not None else throw.start.t_ns + int(round(_last_time(throw) * 1e9))
        diagnosis = Diagnosis(switch_id=throw.switch_id, throw_index=throw.start.throw_index,
                              direction=throw.start.direction, t_start_ns=throw.start.t_ns, t_end_ns=end_ns,
                              model=self.model, decision=decision, reason=reason, hypotheses=hypotheses,
                              joint=joint, latency_ms=(time.perf_counter() - start) * 1e3)
        return DiagnosedThrow(throw, diagnosis, verdict)


def _last_time(throw: CutThrow) -> float:
    return float(throw.t_s[-1]) if len(throw.t_s) else 0.0


def throw_input(throw: CutThrow) -> ThrowInput:
    """What the diagnosis needs from a cut throw."""
    start, end = throw.start, throw.end
    reference = Reference(np.asarray(start.reference_t_s, dtype=float), np.asarray(start.reference_velocity_rad_s, dtype=float))
    return ThrowInput(start.direction, reference, throw.t_s, throw.signals,
                      None if end is None else (end.t_ns - start.t_ns) * 1e-9, throw.missing_samples)


def diagnose_simulation(diagnoser: Diagnoser, switch_id: str, sim: SwitchSimulation, throws: int) -> list[DiagnosedThrow]:
    """Run `throws` throws of a simulated switch and diagnose each, as the bus would carry them."""
    return list(diagnose_messages((message for _, message in switch_messages(switch_id, sim, throws)), diagnoser))


def diagnose_messages(messages: Iterable[Message], diagnoser: Diagnoser) -> Iterator[DiagnosedThrow]:
    """Every throw of an ordered message stream, in the order the throws end; unfinished ones last."""
    cutter = ThrowCutter()
    for message in messages:
        throw = cutter.feed(message)
        if throw is not None:
            yield diagnoser.diagnose(throw)
    for throw in cutter.flush():
        yield diagnoser.diagnose(throw)
