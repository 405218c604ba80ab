import pytest

from models.plant import Plant


@pytest.fixture(scope="session")
def plant() -> Plant:
    """One plant per test session: building its CasADi functions takes a moment."""
    return Plant()
