"""The services' supervisor (services/adapters/processes.py) says which child failed: the demo's recording was
once left unfinished by a recorder that did not end well, and the demo still exited 0."""
from __future__ import annotations

from railswitch.services.adapters.processes import ServiceProcesses, free_loopback_endpoint
from tests.live import client, wait_for


def test_a_child_that_exits_with_an_error_or_is_killed_is_named_with_its_log_and_one_that_stops_is_not(tmp_path):
    services = ServiceProcesses(tmp_path, grace_s=30.0)
    endpoint = free_loopback_endpoint()
    router = services.start("router", "--listen", endpoint)
    failing = services.start("recorder", "--out", str(tmp_path / "missing" / "run.mcap"))
    assert failing.wait(60) == 2
    client(endpoint).close()  # the router is up
    services.stop_all()
    assert router.returncode == 0 and services.killed == []
    report = services.failures()
    assert report.startswith(f"recorder (pid {failing.pid}) exited with code 2; its last lines:")
    assert "does not exist" in report and "router" not in report

    stubborn = ServiceProcesses(tmp_path, grace_s=0.0)  # no time to stop: killed at once
    endpoint = free_loopback_endpoint()
    router = stubborn.start("router", "--listen", endpoint)
    wait_for(lambda: client(endpoint).close() is None, 30, "the router")
    stubborn.stop_all()
    assert stubborn.killed == [router]
    assert stubborn.failures().startswith(f"router (pid {router.pid}) did not stop within 0 s of SIGINT and was killed")


def test_a_service_sent_large_payloads_by_a_shared_memory_peer_still_stops_on_its_first_sigint(tmp_path):
    """Zenoh's shared memory, on by default for payloads over 3 KiB between processes of one host, takes SIGINT and
    SIGTERM from Python when it starts in a process; our sessions turn it off (zenoh_bus.zenoh_config). A recorder
    that had taken such payloads from a peer with Zenoh's defaults went on recording after its stop signal."""
    import json

    import zenoh

    from railswitch.services.adapters.processes import wait_ready

    services = ServiceProcesses(tmp_path, grace_s=20.0)
    endpoint = free_loopback_endpoint()
    services.start("router", "--listen", endpoint)
    recorder = services.start("recorder", "--connect", endpoint, "--out", str(tmp_path / "run.mcap"),
                              "--status-interval", "0.5")
    ours = client(endpoint)
    config = zenoh.Config()  # a foreign client: Zenoh's defaults, shared memory on
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    foreign = zenoh.open(config)
    received = []
    try:
        wait_ready(ours, services, 60, recorder=1)
        ours.declare_subscriber("railswitch/@service/recorder/*/status",
                                lambda sample: received.append(json.loads(sample.payload.to_bytes())["received"]))
        big = json.dumps({"switch_id": "sw1", "padding": "x" * 20_000}).encode()
        for _ in range(20):  # Zenoh drops a put its queues cannot take at once unless told to block
            foreign.put("railswitch/sw1/record", big, congestion_control=zenoh.CongestionControl.BLOCK)
        try:
            wait_for(lambda: received and received[-1] >= 20, 30, "the recorder to take the large payloads")
        except TimeoutError as error:
            raise AssertionError(f"{error}; it reported {received[-3:]} received") from error
        code = services.stop(recorder)  # SIGINT, and SIGKILL at the end of the grace period
    finally:
        foreign.close()
        ours.close()
        services.stop_all()
    assert services.killed == [] and code == 0, services.failures()


# Started in a service process (through PYTHONPATH) before its command runs: once the service has installed its
# Python handler, a "native library" sets SIGINT's C-level handler to one that never tells Python (SIG_IGN here),
# as Zenoh's shared memory did, then its thread ends. Its thread blocks the stop signals, as a library's thread that
# the service starts inherits them blocked: the kernel hands a process's signal to any thread that does not block it,
# and this thread, alive for a moment after it prints, would drop the test's SIGINT under SIG_IGN.
TAKES_SIGINT = '''
import ctypes, signal, threading, time

def take_sigint():
    signal.pthread_sigmask(signal.SIG_BLOCK, (signal.SIGINT, signal.SIGTERM))
    deadline = time.monotonic() + 60
    while signal.getsignal(signal.SIGINT) is signal.default_int_handler and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    ctypes.CDLL(None).signal(int(signal.SIGINT), ctypes.c_void_p(1))  # SIG_IGN, behind Python's back
    print("sitecustomize: SIGINT taken from Python", flush=True)

threading.Thread(target=take_sigint, daemon=True).start()
'''


def test_a_service_whose_signal_handler_a_native_library_replaced_still_stops_on_its_first_sigint(tmp_path,
                                                                                               monkeypatch):
    """A service takes its stop signals with sigwait (zenoh_bus.wait_for_stop_signals), so whichever handler a library
    installs, one SIGINT finishes the recording."""
    from mcap.reader import make_reader

    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(TAKES_SIGINT)
    services = ServiceProcesses(tmp_path, grace_s=20.0)
    endpoint = free_loopback_endpoint()
    services.start("router", "--listen", endpoint)
    monkeypatch.setenv("PYTHONPATH", str(site))
    out = tmp_path / "run.mcap"
    recorder = services.start("recorder", "--connect", endpoint, "--out", str(out))
    monkeypatch.delenv("PYTHONPATH")
    try:
        wait_for(lambda: "SIGINT taken from Python" in services.log(recorder), 60, "the recorder's handler replaced")
        code = services.stop(recorder)
    finally:
        services.stop_all()
    assert services.killed == [] and code == 0, services.failures()
    with out.open("rb") as stream:
        assert make_reader(stream).get_summary() is not None  # the file was finished
