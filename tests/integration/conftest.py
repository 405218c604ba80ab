"""Fixtures of the integration tests."""
import pytest

from railswitch.services.wiring import Diagnoser


@pytest.fixture(scope="module")
def diagnoser() -> Diagnoser:
    """The default representation, compiled once; a module's switches are its own."""
    d = Diagnoser("poly")
    d.warm_up()
    return d
