"""The tests' own state: baselines commissioned by any test (or by the services it starts, which inherit the
environment) land in a folder of the test session, never in the developer's ~/.local/state."""
import os
import subprocess
import sys
from pathlib import Path

from railswitch.services.adapters.baseline_store import default_directory


def test_baselines_go_to_a_folder_of_the_test_session_in_this_process_and_in_service_processes(tmp_path_factory):
    session_folder = tmp_path_factory.getbasetemp()
    assert default_directory().is_relative_to(session_folder)
    assert not default_directory().is_relative_to(Path.home() / ".local" / "state")
    child = subprocess.run([sys.executable, "-c", "from railswitch.services.adapters.baseline_store import "
                            "default_directory; print(default_directory())"], capture_output=True, text=True,
                           env={**os.environ, "XDG_STATE_HOME": ""}, check=True)
    assert Path(child.stdout.strip()).is_relative_to(session_folder)


def test_a_stored_state_reads_back_as_saved_with_non_finite_and_extreme_numbers(tmp_path):
    """A switch's state is written by pydantic's JSON encoder (json.dumps took nine times as long): every float reads
    back as saved, the non-finite ones too (json's NaN and Infinity, not null), and nothing is left half-written."""
    import math

    import numpy as np

    from railswitch.services.adapters.baseline_store import BaselineStore
    store = BaselineStore("poly", tmp_path)
    values = [float(v) for v in np.random.default_rng(1).standard_normal(1000) * 10.0 ** np.arange(-300, 300, 0.6)]
    state = {"baseline": {"levels": values, "numpy": np.float64(0.1), "count": 3, "note": "é", "none": None},
             "health": {"odd": [math.inf, -math.inf, math.nan, 5e-324, 1.7976931348623157e308]}}
    store.save("sw1", state)
    loaded = store.load("sw1")
    assert loaded["baseline"] == {**state["baseline"], "numpy": 0.1}
    odd = loaded["health"]["odd"]
    assert odd[:2] == [math.inf, -math.inf] and math.isnan(odd[2]) and odd[3:] == [5e-324, 1.7976931348623157e308]
    assert sorted(p.name for p in (tmp_path / "poly").iterdir()) == ["sw1.json"]
