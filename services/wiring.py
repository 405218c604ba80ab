"""Where the application meets the outside systems: the diagnoser as commands, the Python API, benchmarks and
tests use it, with the stored reduced models (services/adapters/model_store.py) and the per-machine cache of their
machine code (services/adapters/compiled.py). services/core stays free of both (docs/architecture.md)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from railswitch.models.reduced.hybrid import Compiler
from railswitch.services.adapters import model_store
from railswitch.services.adapters.compiled import MachineCode
from railswitch.services.core import fleet_diagnoser
from railswitch.services.ports import ModelSource


@dataclass
class Diagnoser(fleet_diagnoser.Diagnoser):
    """services/core/fleet_diagnoser.py Diagnoser with the stored models and their machine code."""

    models: ModelSource | None = model_store
    machine_code: Callable[[], Compiler] | None = MachineCode
