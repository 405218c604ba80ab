"""`railswitch serve ...` as real processes through a real router: the same services as their aliases (issue 41)."""
from __future__ import annotations

from railswitch.schemas import MotorSample, encode
from railswitch.services.adapters.processes import free_loopback_endpoint, instance_of
from railswitch.services.adapters.recordings import load_recording
from tests.live import ServiceProcesses, ServiceWatch, client, motor_sample, wait_for


def test_serve_router_and_serve_recorder_run_and_record_what_the_bus_carries(tmp_path):
    recording = tmp_path / "served.mcap"
    sent = [motor_sample(k, 1_000_000_000 + k * 20_000_000) for k in range(20)]
    with ServiceProcesses(tmp_path) as services:
        endpoint = free_loopback_endpoint()
        services.start("serve", "router", "--listen", endpoint)
        session = client(endpoint)
        try:
            watch = ServiceWatch(session, "recorder")
            recorder = services.start("serve", "recorder", "--connect", endpoint, "--out", str(recording),
                                      "--status-interval", "0.2")
            exited = lambda: services.log(recorder, 8) if recorder.poll() is not None else None  # noqa: E731
            wait_for(lambda: watch.latest(instance_of(recorder)) is not None, 120, "the served recorder's status",
                     abort=exited)
            publisher = session.declare_publisher("railswitch/sw1/motor")
            for sample in sent:
                publisher.put(encode(sample))
            wait_for(lambda: (watch.latest(instance_of(recorder)).counters.get("written", 0) >= len(sent)), 30,
                     "the recorder to write every sample", abort=exited)
            assert services.stop(recorder) == 0, services.log(recorder)
        finally:
            session.close()
    kept = [m for m in load_recording(recording).messages if isinstance(m, MotorSample)]
    assert [m.seq for m in kept] == [s.seq for s in sent]
