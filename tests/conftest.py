"""Test levels by folder: tests/unit (pure, seconds), tests/integration (real files, compilers, a real router,
subprocesses of the command line), tests/e2e (whole services as processes: live runs, crashes, restarts).
`python -m pytest tests/unit -q` is the quick check; the README's command runs everything."""
from pathlib import Path

import pytest

from railswitch.models.plant.high_fidelity import Plant

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


@pytest.fixture(autouse=True, scope="module")
def module_state_directory(tmp_path_factory):
    """The same for what a module-scoped fixture runs (a live run several tests read): it starts before any test's
    own folder is set, and without this would write the developer's default folder, where every run of the suite
    left its switches (sw `faulty` kept on growing a history until its trend fit failed)."""
    patch = pytest.MonkeyPatch()
    patch.setenv("RAILSWITCH_STATE", str(tmp_path_factory.mktemp("module-state")))
    yield
    patch.undo()


@pytest.fixture(autouse=True)
def own_state_directory(tmp_path_factory, monkeypatch):
    """Baselines the diagnosers of a test commission (in this process and in every service process it starts) go
    to a folder of that test: never into the developer's ~/.local/state, and never into another test's. A diagnoser
    resumes every switch it finds there, present faults included, and tests reuse switch ids (sw1 with an obstacle
    in one test was still carrying it in the next)."""
    monkeypatch.setenv("RAILSWITCH_STATE", str(tmp_path_factory.mktemp("state")))


@pytest.fixture(scope="session")
def postgres():
    """A private PostgreSQL server for the session (tests/postgres.py); the tests skip, in one line, without one."""
    from tests.postgres import PostgresServer, binaries

    found = binaries()
    if found is None:
        pytest.skip("no PostgreSQL binaries (initdb, pg_ctl) on PATH or in /usr/lib/postgresql/*/bin")
    with PostgresServer(found) as server:
        yield server


@pytest.fixture
def pg_url(postgres) -> str:
    """The URL of a fresh, empty database of its own on the session's server."""
    return postgres.new_database()


@pytest.fixture(scope="session")
def plant() -> Plant:
    """One plant per test session: building its CasADi functions takes a moment."""
    return Plant()
