"""Bad command-line values of the live services: one line naming them, exit code 2."""
import subprocess
import sys

import pytest

from railswitch.services.adapters.processes import free_loopback_endpoint
from tests.live import ROOT


@pytest.mark.parametrize("args, words", [
    (["diagnoser", "--shard", "3/2"], "shard 3/2 is outside the accepted range"),
    (["simulator", "--speed", "0"], "0 is outside the accepted range"),
    (["simulator", "--connect", "nowhere"], "bad endpoint"),
    (["simulator", "--switches", "2", "--switch-id", "a"], "not both"),
    (["recorder", "--out", "/nonexistent-dir/x.mcap"], "does not exist"),
    (["replay", "/nonexistent.mcap"], "cannot read"),
    (["notify", "--webhook", "http://127.0.0.1:9/", "--header", "no colon"], "'no colon' is not a header 'Name: value' in printable ASCII"),
    (["notify", "--webhook", "http://127.0.0.1:9/", "--header", "X-Token: é"], "is not a header 'Name: value'"),
    (["notify", "--webhook", "http://127.0.0.1:9/", "--timeout", "0"], "0 is outside the accepted range 0.1 … 300 s"),
])
def test_bad_service_options_give_one_line_and_exit_2(args, words):
    result = subprocess.run([sys.executable, "-m", "railswitch", *args], cwd=ROOT, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2, result.stderr
    assert words in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.mark.parametrize("url", ["ftp://x", "notaurl", "http://", "http://127.0.0.1:99999/", "http://a b/"])
def test_a_bad_webhook_url_gives_one_line_and_exit_2_before_joining_the_bus(url):
    endpoint = free_loopback_endpoint()  # nobody listens: a notifier that went on to the bus would wait there
    result = subprocess.run([sys.executable, "-m", "railswitch", "notify", "--webhook", url, "--connect", endpoint],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert result.stderr == (f"railswitch notify: error: argument --webhook: {url!r} must be an http:// or https:// URL "
                             "with a host\n")


@pytest.mark.parametrize("args, words", [
    (["simulate", "--out", "x.mcap", "--plant", "motor.supply_v=300"], "outside the accepted range 40 … 140 V"),
    (["simulate", "--out", "x.mcap", "--plant", "motor.bogus=1"], "unknown plant parameter"),
    (["simulate", "--out", "x.mcap", "--vary"], "expected one argument"),
    (["simulator", "--plant", "rail.heel_flex_factor=1"], "outside the accepted range"),
    (["commission", "not a switch!"], "must be 1 to 64 letters"),
])
def test_bad_switch_parameters_give_one_line_and_exit_2(args, words, tmp_path):
    result = subprocess.run([sys.executable, "-m", "railswitch", *args], cwd=tmp_path, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2, result.stderr
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args, words", [
    (["--records", "--commissioning", "-1"], "--commissioning -1 is outside the accepted range"),
    (["--records", "--burst-throws", "0"], "--burst-throws 0 is outside the accepted range"),
    (["--elastic"], "--elastic needs --records"),
])
def test_bad_bus_benchmark_options_give_one_line_and_exit_2(args, words):
    result = subprocess.run([sys.executable, "-m", "benchmarks.bus", *args], cwd=ROOT, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2, result.stderr
    assert words in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
