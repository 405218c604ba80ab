"""The diagnoser's core, shared by `railswitch diagnose` (offline) and the live diagnoser.

Turns cut throws into `Diagnosis` messages: one SwitchDiagnoser per switch (its baseline, latest
verdicts and the decided fault's history) and one compiled estimator per process, which serves
throws of any length and rate. A switch's state (baseline and health) is handed to `on_state` after
every throw, so the live diagnoser can keep it on disk (or on the bus) and resume it after a restart.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from railswitch.models.health.alarms import AlarmBook, Change, Condition
from railswitch.models.diagnosis.estimation import MODEL_RATE_HZ, WITHOUT, ThrowEstimator
from railswitch.models.reduced.hybrid import BearingPort, Compiler, ReducedParams, ReducedSwitch, port_pairs
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.models.diagnosis.switch_diagnoser import (
    ErrorModel,
    Outcome,
    Population,
    SwitchDiagnoser,
    ThrowVerdict,
    population,
)
from railswitch.models.health.prognosis import Health
from railswitch.models.diagnosis.isolation import OTHER_DIRECTION
from railswitch.schemas import (
    FAULT_PARAMETERS,
    MODE_PARAMETERS,
    RAIL_MODELS,
    Alarm,
    Anomaly,
    Commissioning,
    FeatureHealth,
    ThrowFeatures,
    Diagnosis,
    FaultEstimate,
    Hypothesis,
    Message,
    ParameterHealth,
    SwitchHealth,
)
from railswitch.services.ports import ModelSource
from railswitch.services.core.switch_messages import switch_messages
from railswitch.services.core.records import every_throw
from railswitch.services.core.throw_cutter import CutThrow

log = logging.getLogger("railswitch.diagnoser")


@dataclass(frozen=True)
class DiagnosedThrow:
    """A throw, its Diagnosis and SwitchHealth messages and (when it was fitted) the verdict with every estimate."""

    throw: CutThrow
    diagnosis: Diagnosis
    verdict: ThrowVerdict | None
    health: SwitchHealth | None = None
    alarms: tuple[Alarm, ...] = ()  # the changes of the switch's alarms this throw made


@dataclass
class Diagnoser:
    """Diagnoses throws of any number of switches with one reduced model."""

    model: str = "poly"
    compiled: bool = True
    port: BearingPort | None = None  # the bearing port per direction; None: the stored model's
    on_state: Callable[[str, dict], None] | None = None  # (switch id, state) after every throw and commissioning
    stored_state: Callable[[str], dict | None] | None = None  # a switch's state kept from an earlier run
    switches: dict[str, SwitchDiagnoser] = field(default_factory=dict)
    # per switch: (throw index, end ns) of the latest throw its state has seen, kept in the state as `last_throw`
    last_throws: dict[str, tuple[int, int]] = field(default_factory=dict)
    books: dict[str, AlarmBook] = field(default_factory=dict)  # per switch: its open alarms, kept in its state
    maintenance: dict[str, dict] = field(default_factory=dict)  # switches in maintenance: since when, why
    lean: bool = False  # keep about half as much per switch, for a little more time per throw (SwitchDiagnoser)
    # Where the model comes from, and what makes it machine code (None: interpreted): services/wiring.py's
    # Diagnoser gives the stored models and the per-machine compiler cache.
    models: ModelSource | None = None
    machine_code: Callable[[], Compiler] | None = None

    def __post_init__(self) -> None:
        if self.model not in RAIL_MODELS:
            raise ValueError(f"unknown model {self.model!r}; accepted: {', '.join(RAIL_MODELS)}")
        self._estimator: ThrowEstimator | None = None
        self._prior: Population | None = None
        self._errors = ErrorModel()

    @property
    def estimator(self) -> ThrowEstimator:
        """The estimator, built (and compiled, once per machine: services/adapters/compiled.py) on first use."""
        if self._estimator is None:
            if self.models is None:
                raise RuntimeError("a Diagnoser needs its models' source (services/wiring.py Diagnoser gives the "
                                   "stored ones)")
            stored = self.models.load(self.model)
            if not stored.healthy_check.get("passed", True):
                log.warning("model %s (%s) failed its check on held-out healthy switches: %s false alarms per 1000 "
                            "throws (limit %s); expect false alarms", self.model, stored.path,
                            stored.healthy_check.get("per_1000_throws"), stored.healthy_check.get("limit_per_1000_throws"))
            params = ReducedParams(bearing_port=port_pairs(self.port or stored.bearing_port))
            reduced = ReducedSwitch(stored.representation, stored.weights, params, rate_hz=MODEL_RATE_HZ)
            self._machine_code = self.machine_code() if self.compiled and self.machine_code else None
            self._estimator = ThrowEstimator(reduced, self._machine_code)
            self._prior = population(stored.healthy_gains, stored.model_weight)
            self._errors = ErrorModel(**stored.error_model)
        return self._estimator

    @property
    def compiles(self) -> int:
        """How many times this diagnoser made its model machine code (once, whatever the throws' lengths and rates)."""
        machine_code = getattr(self, "_machine_code", None)
        return machine_code.calls if machine_code is not None else 0

    def warm_up(self) -> None:
        """Build (and compile) the estimator before the first throw arrives."""
        self.estimator

    def switch(self, switch_id: str) -> SwitchDiagnoser:
        """The diagnoser of one switch: resumed from its stored baseline, else commissioning afresh."""
        if switch_id not in self.switches:
            estimator = self.estimator
            switch = SwitchDiagnoser(estimator, self._prior, self._errors, lean=self.lean)
            stored = self.stored_state(switch_id) if self.stored_state is not None else None
            if stored is not None:
                switch.resume(stored)
                if "last_throw" in stored:  # a state saved before it was kept has none
                    self.last_throws[switch_id] = (int(stored["last_throw"][0]), int(stored["last_throw"][1]))
            self.books[switch_id] = AlarmBook.from_dict(stored.get("alarms") if stored else None)
            if stored is not None and stored.get("maintenance"):
                self.maintenance[switch_id] = dict(stored["maintenance"])
            self.switches[switch_id] = switch
        return self.switches[switch_id]

    def forget(self, switch_id: str) -> None:
        """Drop a switch held here; its next throw resumes it from its latest stored state."""
        self.switches.pop(switch_id, None)
        self.last_throws.pop(switch_id, None)
        self.books.pop(switch_id, None)
        self.maintenance.pop(switch_id, None)

    def commission(self, switch_id: str, accept: bool = False) -> dict[str, dict[str, float]]:
        """Restart a switch's commissioning (after maintenance), or with `accept` take the switch as it now is as its
        own (its present faults become its baseline); returns what was accepted."""
        switch = self.switch(switch_id)
        accepted = switch.accept() if accept else {}
        if not accept:
            switch.restart_commissioning()
        self._saved(switch_id)
        return accepted

    def _saved(self, switch_id: str) -> None:
        """The switch's whole state (its diagnoser's, alarms, maintenance, latest throw) handed to on_state."""
        if self.on_state is None:
            return
        state = {**self.switches[switch_id].state(), "alarms": self.books[switch_id].to_dict()}
        if switch_id in self.maintenance:
            state["maintenance"] = self.maintenance[switch_id]
        if switch_id in self.last_throws:
            state["last_throw"] = list(self.last_throws[switch_id])
        self.on_state(switch_id, state)

    def acknowledge(self, switch_id: str, t_ns: int, alarm: str | None = None, note: str | None = None) -> list[Alarm]:
        """Acknowledge a switch's alarms (all, or the one named); the changes, none when there was nothing to
        acknowledge."""
        self.switch(switch_id)
        latest = self.last_throws.get(switch_id)  # a change never comes before the one it follows (the throw's clock
        t_ns = max(t_ns, latest[1] if latest else 0)  # may be a simulator's, ahead of this one's)
        changes = self.books[switch_id].acknowledge(t_ns, alarm, note)
        if changes:
            self._saved(switch_id)
        return [alarm_message(self.model, switch_id, change) for change in changes]

    def set_maintenance(self, switch_id: str, start: bool, t_ns: int, recommission: bool = False,
                        note: str | None = None) -> bool:
        """Start or end a switch's maintenance (at its end, optionally learning its baseline again); False when it was
        already so (a repeated command changes nothing)."""
        switch = self.switch(switch_id)
        if start == (switch_id in self.maintenance):
            return False
        if start:
            self.maintenance[switch_id] = {"since_ns": t_ns, "note": note}
        else:
            del self.maintenance[switch_id]
            if recommission:
                switch.restart_commissioning()
        self._saved(switch_id)
        return True

    def diagnose(self, throw: CutThrow, waited_s: float = 0.0) -> DiagnosedThrow:
        """The Diagnosis of one throw, with the alarm changes it made; latency_ms is how long the throw `waited_s`
        before this call (the live diagnoser's: since its end arrived) plus the call's own wall time. A switch in
        maintenance is diagnosed aside: its throw is tagged, raises no alarm and teaches nothing."""
        start = time.perf_counter() - waited_s
        switch_id = throw.switch_id
        switch = self.switch(switch_id)
        maintenance = switch_id in self.maintenance
        outcome = (switch.diagnose_aside if maintenance else switch.diagnose)(throw)
        if outcome.standing is not None:
            log.warning("%s %s", switch_id, outcome.standing)
        end_ns = throw_end_ns(throw)
        changes = []
        if not maintenance and outcome.verdict is not None:
            conditions, judged = alarm_conditions(outcome, throw.start.direction, self.books[switch_id])
            changes = self.books[switch_id].observe(throw.start.throw_index, end_ns, conditions, judged)
        self.last_throws[switch_id] = (throw.start.throw_index, end_ns)
        self._saved(switch_id)
        diagnosis = diagnosis_message(self.model, throw, switch, outcome, (time.perf_counter() - start) * 1e3, end_ns,
                                      maintenance)
        health = None if outcome.health is None else health_message(self.model, throw, outcome.health, end_ns,
                                                                       outcome.feature_health)
        alarms = tuple(alarm_message(self.model, switch_id, change) for change in changes)
        return DiagnosedThrow(throw, diagnosis, outcome.verdict, health, alarms)


def alarm_conditions(outcome: Outcome, direction: str, book: AlarmBook) -> tuple[dict[str, Condition], set[str]]:
    """What a throw's outcome raises alarms for, by alarm id, and the open alarms it judged: each present fault (its
    severity from its health: medium, high when watched, critical at its alarm; low while the switch is provisional),
    each anomaly (high) and, on a switch with neither, one alarm for the features of this direction outside their
    band (low): beside a fault they are its symptoms, one alarm each was noise in the control room."""
    conditions = {}
    states = {} if outcome.health is None else {name: p.state for name, p in outcome.health.parameters.items()}
    provisional = outcome.verdict is not None and outcome.verdict.provisional
    for mode in outcome.faults:
        names = MODE_PARAMETERS[mode]
        worst = max((states.get(name, "ok") for name in names), key=("ok", "watch", "alarm").index)
        severity = "low" if provisional else {"ok": "medium", "watch": "high", "alarm": "critical"}[worst]
        estimate = outcome.estimates.get(mode)
        params = dict(estimate.params) if estimate is not None else {}
        sizes = ", ".join(f"{name} {value:.4g} {FAULT_PARAMETERS[name].unit}" for name, value in params.items())
        conditions[mode] = Condition("fault", severity, f"{mode}{': ' + sizes if sizes else ''}", params)
    for anomaly in outcome.anomalies:
        value = anomaly["value"]
        conditions[f"anomaly:{anomaly['quantity']}"] = Condition(
            "anomaly", "high", anomaly["reason"], {anomaly["quantity"]: value} if value is not None else {})
    outside = [f for f in outcome.feature_health if f["state"] == "outside"]
    if outside and not conditions:  # a fault or an anomaly explains its features; they would only repeat it
        conditions[f"features:{direction}"] = Condition(
            "feature", "low", f"{direction.replace('_', ' ')}: " + "; ".join(
                f"{f['name']} {f['value']:.4g}, outside its commissioned band {f['low']:.4g} … {f['high']:.4g}"
                for f in outside), {f["name"]: f["value"] for f in outside})
    judged = {alarm for alarm in book.alarms if not alarm.endswith(f":{OTHER_DIRECTION[direction]}")}
    return conditions, judged


def alarm_message(model: str, switch_id: str, change: Change) -> Alarm:
    state = change.alarm
    return Alarm(switch_id=switch_id, alarm=state.alarm, change=change.change, severity=state.severity,
                 cause=state.cause, text=state.text[:500], parameters=state.parameters, first_throw=state.first_throw,
                 last_throw=state.last_throw, count=state.count, active=state.active, acknowledged=state.acknowledged,
                 note=state.note, sequence=change.sequence, t_ns=change.t_ns, model=model)


def health_message(model: str, throw: CutThrow, health: Health, end_ns: int, features: list[dict] = ()) -> SwitchHealth:
    """The SwitchHealth of a switch after a throw (parameters never seen yet are left out), with its features' trends
    in the throw's direction."""
    def finite(value):
        return None if value is None or not np.isfinite(value) else float(value)

    parameters = [ParameterHealth(name=h.name, level=h.level, level_std=finite(h.level_std), slope_per_100=h.slope_per_100,
                                  slope_std_per_100=finite(h.slope_std_per_100), limit=h.limit,
                                  throws_to_limit=finite(h.throws_to_limit), throws_to_limit_low=finite(h.throws_to_limit_low),
                                  throws_to_limit_high=finite(h.throws_to_limit_high), state=h.state)
                  for h in health.parameters.values() if np.isfinite(h.level_std)]
    worst = health.parameters.get(health.worst) if health.worst else None
    return SwitchHealth(switch_id=throw.switch_id, throw_index=throw.start.throw_index, t_ns=end_ns, model=model,
                        state=health.state, worst=health.worst,
                        throws_to_limit=finite(worst.throws_to_limit) if worst else None, parameters=parameters,
                        features=[FeatureHealth(**feature) for feature in features])


def diagnosis_message(model: str, throw: CutThrow, switch: SwitchDiagnoser, outcome: Outcome, latency_ms: float,
                      end_ns: int, maintenance: bool = False) -> Diagnosis:
    """The Diagnosis of a throw's outcome (docs/contracts.md section 3), tagged as a monitor's trace list shows it."""
    hypotheses, without, joint = [], [], None
    verdict = outcome.verdict
    if verdict is not None:
        for label, reported in verdict.reported.items():
            hypothesis = Hypothesis(mode=reported.mode, params=reported.params, std=reported.std, mse=reported.mse,
                                    unobservable=list(reported.unobservable), nuisance=reported.nuisance)
            if label == "joint":
                joint = hypothesis
            elif label.startswith(WITHOUT):
                without.append(hypothesis)
            else:
                hypotheses.append(hypothesis)
    estimates = {mode: FaultEstimate(mode=e.mode, params=e.params, std=e.std, throws=e.throws, since_throw=e.since_throw)
                 for mode, e in outcome.estimates.items()}
    baseline = switch.baseline
    commissioning = Commissioning(state="commissioned" if baseline.complete else "provisional",
                                  throws={d: min(baseline.count(d), baseline.needed) for d in baseline.healthy},
                                  needed=baseline.needed, outside_population=switch.outside_population(),
                                  standing=switch.standing if not baseline.complete else None,
                                  accepted=baseline.accepted)
    anomalies = [Anomaly(**anomaly) for anomaly in outcome.anomalies]
    faults = sorted([*outcome.faults, *(["anomaly"] if anomalies else [])])
    tag = ("maintenance" if maintenance else "unknown" if outcome.decision == "unknown" else
           "anomaly" if anomalies else "fault" if outcome.faults else "normal")
    return Diagnosis(switch_id=throw.switch_id, throw_index=throw.start.throw_index, direction=throw.start.direction,
                     t_start_ns=throw.start.t_ns, t_end_ns=end_ns, model=model, decision=outcome.decision,
                     reason=outcome.reason, hypotheses=hypotheses, joint=joint,
                     estimate=estimates.get(outcome.decision), commissioning=commissioning, latency_ms=latency_ms,
                     signals=list(throw.signals.names) if verdict is not None else [],
                     faults=faults, estimates=list(estimates.values()), without=without,
                     features=ThrowFeatures(**outcome.features) if outcome.features else None, anomalies=anomalies,
                     tag=tag)


def throw_end_ns(throw: CutThrow) -> int:
    """When a throw ended: its end event, else its last sample."""
    return throw.end.t_ns if throw.end is not None else throw.start.t_ns + int(round(_last_time(throw) * 1e9))


def _last_time(throw: CutThrow) -> float:
    return float(throw.t_s[-1]) if len(throw.t_s) else 0.0


def diagnose_simulation(diagnoser: Diagnoser, switch_id: str, sim: SwitchSimulation, throws: int) -> list[DiagnosedThrow]:
    """Run `throws` throws of a simulated switch and diagnose each, as the bus would carry them."""
    return list(diagnose_messages((message for _, message in switch_messages(switch_id, sim, throws)), diagnoser))


def diagnose_messages(messages: Iterable[Message], diagnoser: Diagnoser) -> Iterator[DiagnosedThrow]:
    """Every throw of an ordered message stream (samples or records), in the order the throws end; unfinished ones
    last."""
    for throw in every_throw(messages):
        yield diagnoser.diagnose(throw)
