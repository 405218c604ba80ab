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
