"""The demo's story and what it saw against it: switches drawn from the population that throw healthily until
commissioned, then with one fault mode each (cycling through the five); each throw's decision held against the
injected truth, and each switch's health after its last throw (railswitch demo, benchmarks.soak)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rich.table import Table

from railswitch.models.diagnosis.estimation import DRIVING_BOLT
from railswitch.models.diagnosis.switch_diagnoser import COMMISSIONING_THROWS
from railswitch.schemas import FAULT_PARAMETERS, Diagnosis, FaultTruth, SwitchHealth
from railswitch.services.core.tables import state_markup, to_limit

DEMO_FAULTS = (  # the paper's four scenarios, and a worn point machine
    {"left_bolt_offset": 0.05},
    {"right_bolt_offset": 0.20},
    {"bearing_friction": 5000.0},
    {"obstacle_friction": 1.0e5, "obstacle_position": 1.10},
    {"drive_friction_nm": 0.1},
)
NOISE = 0.01
INTERVAL_S = 10.0


def fault_onset(throws: int) -> int:
    """The throw the demo's faults start at: once the switches are commissioned, when there are throws enough."""
    commissioning = 2 * COMMISSIONING_THROWS
    return commissioning if throws > commissioning else throws // 2


def demo_scenario(switches: int, throws: int) -> str:
    """TOML for `railswitch simulator --scenario`: switches drawn from the population, 1 % noise, healthy until
    fault_onset, then fault mode k mod 5."""
    lines = [f"interval_s = {INTERVAL_S}", f"noise = {NOISE}", ""]
    for k in range(switches):
        faults = DEMO_FAULTS[k % len(DEMO_FAULTS)]
        values = ", ".join(f"{name} = {value!r}" for name, value in faults.items())
        lines += ["[[switches]]", f'id = "sw{k + 1}"', f"throws = {throws}", f"vary = {k + 1}", "",
                  "[[switches.changes]]", f"throw = {fault_onset(throws)}", f"set = {{ {values} }}", ""]
    return "\n".join(lines)


def connect_endpoint(listen: str) -> str:
    """Where local processes reach a router listening on `listen` (any-address becomes loopback)."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]", "::", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


@dataclass
class DemoOutcome:
    """What the demo saw: the diagnoses and the truth messages, per switch."""

    diagnoses: list[Diagnosis] = field(default_factory=list)
    truths: dict[str, list[FaultTruth]] = field(default_factory=dict)
    health: dict[str, SwitchHealth] = field(default_factory=dict)  # each switch's latest

    def take(self, message: Diagnosis | SwitchHealth | FaultTruth, latest: dict[str, Diagnosis]) -> bool:
        """Keep a message; whether it is one to show (a diagnosis or health message)."""
        if isinstance(message, FaultTruth):
            self.truths.setdefault(message.switch_id, []).append(message)
            return False
        if isinstance(message, SwitchHealth):
            self.health[message.switch_id] = message
        else:
            self.diagnoses.append(message)
            latest[message.switch_id] = message
        return True

    def truth_at(self, switch_id: str, t_ns: int) -> FaultTruth | None:
        earlier = [t for t in self.truths.get(switch_id, []) if t.t_ns <= t_ns]
        return max(earlier, key=lambda t: t.t_ns) if earlier else None

    def injected(self, diagnosis: Diagnosis) -> list[str]:
        truth = self.truth_at(diagnosis.switch_id, diagnosis.t_start_ns)
        return list(truth.active_modes()) if truth else []

    def expected(self) -> dict[tuple[str, int], str]:
        """The decision each throw should get: its injected mode, where a bolt counts once a throw
        it drives (left bolt: left to right) has run with it, since the other direction cannot see it."""
        out, seen = {}, {}
        for d in sorted(self.diagnoses, key=lambda d: (d.switch_id, d.throw_index)):
            modes = self.injected(d)
            driven = DRIVING_BOLT[d.direction]
            seen[d.switch_id] = {m for m in seen.get(d.switch_id, set()) if m in modes} | (
                {driven} if driven in modes else set())
            visible = [m for m in modes if m not in DRIVING_BOLT.values() or m in seen[d.switch_id]]
            out[d.switch_id, d.throw_index] = "+".join(visible) or "nominal"
        return out

    def summary(self) -> tuple[Table, int]:
        table = Table(title="demo summary: decision of each throw against the injected fault")
        for column in ("switch", "throw", "direction", "injected", "expected", "decided", ""):
            table.add_column(column)
        correct, expected = 0, self.expected()
        for d in sorted(self.diagnoses, key=lambda d: (d.switch_id, d.throw_index)):
            want = expected[d.switch_id, d.throw_index]
            decided = "+".join(d.faults) if d.faults else d.decision  # every present fault
            ok = set(decided.split("+")) == set(want.split("+"))
            correct += ok
            table.add_row(d.switch_id, str(d.throw_index), d.direction, "+".join(self.injected(d)) or "none", want,
                          decided, "[green]✓[/]" if ok else "[red]✗[/]")
        return table, correct

    def health_table(self) -> Table:
        """Each switch's health after its last throw: state, and its worst parameter's level and throws to limit."""
        table = Table(title="health of each switch after its last throw")
        for column in ("switch", "throw", "state", "worst parameter level", "worst: throws to limit"):
            table.add_column(column)
        for switch_id, health in sorted(self.health.items()):
            worst = next((p for p in health.parameters if p.name == health.worst), None)
            level = "" if worst is None else (
                f"{worst.level:.4g}" + ("" if worst.level_std is None else f" ± {worst.level_std:.2g}")
                + f" {FAULT_PARAMETERS[worst.name].unit} (limit {worst.limit:g})")
            table.add_row(switch_id, str(health.throw_index), state_markup(health.state), level, to_limit(health))
        return table


def fresh_history_file(recording: Path) -> Path:
    """The demo's history file next to its recording, emptied: each demo starts its history afresh."""
    history = recording.with_suffix(".sqlite")
    if history == recording:  # --out x.sqlite: the recorder's file is not the historian's
        history = recording.with_name(f"{recording.name}.history.sqlite")
    for leftover in (history, Path(f"{history}-wal"), Path(f"{history}-shm")):
        leftover.unlink(missing_ok=True)
    return history
