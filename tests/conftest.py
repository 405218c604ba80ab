"""Test levels by folder: tests/unit (pure, seconds), tests/integration (real files, compilers, a real router,
subprocesses of the command line), tests/e2e (whole services as processes: live runs, crashes, restarts).
`python -m pytest tests/unit -q` is the quick check; the README's command runs everything."""
from pathlib import Path

import pytest

from railswitch.models.plant import Plant

LEVELS = ("unit", "integration", "e2e")


def pytest_collection_modifyitems(items):
    for item in items:
        level = next((part for part in Path(item.fspath).parts if part in LEVELS), None)
        if level is not None:
            item.add_marker(getattr(pytest.mark, level))


@pytest.fixture(autouse=True, scope="session")
def shipped_models_only(tmp_path_factory):
    """Models a developer trained into their own model directory must not change what the tests see."""
    patch = pytest.MonkeyPatch()
    patch.setenv("RAILSWITCH_MODELS", str(tmp_path_factory.mktemp("user-models")))
    yield
    patch.undo()


@pytest.fixture(autouse=True, scope="session")
def own_state_directory(tmp_path_factory):
    """Baselines the diagnosers of the tests commission (in this process and in every service process they
    start) go to a folder of the session, never into the developer's ~/.local/state."""
    patch = pytest.MonkeyPatch()
    patch.setenv("RAILSWITCH_STATE", str(tmp_path_factory.mktemp("state")))
    yield
    patch.undo()


@pytest.fixture(scope="session")
def plant() -> Plant:
    """One plant per test session: building its CasADi functions takes a moment."""
    return Plant()
