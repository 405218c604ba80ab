"""The MCAP adapter against the official mcap reader, and its behaviour on failure and damage."""

import json
import os
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from railswitch.schemas import (
    Diagnosis,
    FaultCommand,
    FaultTruth,
    Hypothesis,
    Message,
    MotorSample,
    ThrowEvent,
    key_expr,
)
from railswitch.services.adapters.recordings import (
    RecordingPathError,
    RecordingReader,
    RecordingWriter,
    check_writable,
    read_recording,
)

SW = "sw-1"


def sample_messages(n_motor: int = 50) -> list[tuple[str, Message, int]]:
    """(key, message, expected log time) for a short throw with one of every kind."""
    ms = 1_000_000
    motor = [
        MotorSample(
            switch_id=SW,
            seq=i,
            t_ns=i * ms,
            current_a=0.1 * i,
            angle_rad=0.01 * i,
            velocity_rad_s=1.5,
        )
        for i in range(n_motor)
    ]
    throw = ThrowEvent(
        switch_id=SW,
        throw_index=0,
        direction="left_to_right",
        phase="start",
        t_ns=0,
        reference_t_s=[0.0, 0.5, 7.0],
        reference_velocity_rad_s=[0.0, 150.0, 150.0],
    )
    truth = FaultTruth(switch_id=SW, t_ns=0, bearing_friction=2000.0)
    command = FaultCommand(switch_id=SW, params={"left_bolt_offset": 0.05})
    diagnosis = Diagnosis(
        switch_id=SW,
        throw_index=0,
        direction="left_to_right",
        t_start_ns=0,
        t_end_ns=(n_motor - 1) * ms,
        model="poly",
        decision="missing_bearing",
        hypotheses=[
            Hypothesis(mode="missing_bearing", params={"bearing_friction": 1990.0}, mse=0.1)
        ],
        latency_ms=3.0,
    )
    return [
        (key_expr(SW, "throw"), throw, 0),
        (key_expr(SW, "truth"), truth, 0),
        (key_expr(SW, "inject"), command, 5 * ms),
        *((key_expr(SW, "motor"), m, m.t_ns) for m in motor),
        (key_expr(SW, "diagnosis"), diagnosis, n_motor * ms),
    ]


def write_sample(path: Path, **kwargs: object) -> list[tuple[str, Message, int]]:
    """Write sample_messages to path, giving log times only to the kinds without t_ns."""
    messages = sample_messages(**kwargs)  # type: ignore[arg-type]
    with RecordingWriter(path) as writer:
        for key, msg, t in messages:
            writer.write(key, msg, None if hasattr(msg, "t_ns") else t)
    assert writer.message_count == len(messages)
    return messages


def test_official_reader_sees_jsonschema_json_and_t_ns_as_log_time(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    written = write_sample(path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        got = list(reader.iter_messages(log_time_order=False))
        summary = reader.get_summary()
    assert summary is not None
    assert sorted(c.topic for c in summary.channels.values()) == sorted({k for k, _, _ in written})
    assert len(got) == len(written)
    for (schema, channel, record), (key, msg, log_time) in zip(got, written):
        assert schema is not None and schema.encoding == "jsonschema"
        assert schema.name == type(msg).__name__
        assert set(json.loads(schema.data)["properties"]) == set(type(msg).model_fields)
        assert channel.topic == key and channel.message_encoding == "json"
        assert record.log_time == record.publish_time == log_time
        assert json.loads(record.data) == msg.model_dump(mode="json")
    motor_seqs = [r.sequence for _, c, r in got if c.topic.endswith("/motor")]
    assert motor_seqs == list(range(50))


def test_read_recording_gives_back_equal_messages(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    written = write_sample(path)
    got = list(read_recording(path))
    assert [(r.key, r.message, r.log_time_ns) for r in got] == written
    assert {(r.switch_id, r.kind) for r in got} == {
        (SW, k) for k in ("motor", "throw", "truth", "diagnosis", "inject")
    }


def test_same_messages_give_identical_bytes(tmp_path: Path) -> None:
    write_sample(tmp_path / "a.mcap")
    write_sample(tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_exception_inside_with_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    key, msg, _ = sample_messages()[3]
    with pytest.raises(RuntimeError, match="simulation failed"):
        with RecordingWriter(path) as writer:
            writer.write(key, msg)
            assert (tmp_path / ".run.mcap.partial").exists()
            raise RuntimeError("simulation failed")
    assert os.listdir(tmp_path) == []


def test_non_atomic_writer_finishes_a_readable_file_on_exception(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    key, msg, _ = sample_messages()[3]
    with pytest.raises(KeyboardInterrupt):
        with RecordingWriter(path, atomic=False) as writer:
            writer.write(key, msg)
            raise KeyboardInterrupt
    reader = RecordingReader(path)
    assert [r.message for r in reader] == [msg]
    assert reader.damage is None


def test_a_live_writer_finished_early_leaves_a_complete_file_that_leaving_its_with_block_does_not_touch(
        tmp_path: Path) -> None:
    """The recorder finishes its file before it closes its bus session: a recorder killed while closing it (which
    happened on CI) leaves a complete file, not one whose last bytes the reader takes for a summary."""
    path = tmp_path / "live.mcap"
    key, msg, _ = sample_messages()[3]
    with pytest.raises(KeyboardInterrupt):
        with RecordingWriter(path, atomic=False) as writer:
            writer.write(key, msg)
            writer.finish()
            finished = path.read_bytes()
            reader = RecordingReader(path)
            assert [r.message for r in reader] == [msg] and reader.damage is None
            raise KeyboardInterrupt  # as a signal killing the process now would: the file stays as it was
    assert path.read_bytes() == finished
    with pytest.raises(TypeError, match="atomic"):
        with RecordingWriter(tmp_path / "run.mcap") as atomic:
            atomic.finish()


def test_writer_rejects_a_message_of_the_wrong_kind_or_switch(tmp_path: Path) -> None:
    _, motor, _ = sample_messages()[3]
    with RecordingWriter(tmp_path / "run.mcap") as writer:
        with pytest.raises(TypeError, match="carries ThrowEvent, not MotorSample"):
            writer.write(key_expr(SW, "throw"), motor)
        with pytest.raises(ValueError, match="switch_id 'sw-1'"):
            writer.write(key_expr("sw-2", "motor"), motor)
        with pytest.raises(ValueError, match="FaultCommand has no t_ns; pass log_time_ns"):
            writer.write(key_expr(SW, "inject"), FaultCommand(switch_id=SW, reset=True))


def test_missing_directory_raises_recording_path_error_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "no" / "such" / "run.mcap"
    with pytest.raises(RecordingPathError, match=f"{path}.*does not exist"):
        check_writable(path)
    with pytest.raises(RecordingPathError, match=str(path)):
        RecordingWriter(path)


def test_file_in_place_of_directory_raises_recording_path_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    with pytest.raises(RecordingPathError, match="file/run.mcap"):
        check_writable(tmp_path / "file" / "run.mcap")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_directory_raises_recording_path_error(tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    with pytest.raises(RecordingPathError, match=f"{locked / 'run.mcap'}.*not writable"):
        check_writable(locked / "run.mcap")


def test_truncated_file_yields_messages_before_the_cut_and_reports_damage(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    with RecordingWriter(full, chunk_size=4096) as writer:
        for key, msg, t in sample_messages(n_motor=3000):
            writer.write(key, msg, None if hasattr(msg, "t_ns") else t)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    reader = RecordingReader(cut)
    got = [r.message for r in reader]
    expected = [r.message for r in read_recording(full)]
    assert 0 < len(got) < len(expected)
    assert got == expected[: len(got)]
    assert reader.messages_read == len(got)
    assert reader.damage == f"truncated after {len(data) // 2} bytes: the last record is incomplete"


def test_file_that_is_not_mcap_reports_damage_and_no_messages(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_bytes(b"these are not the bytes you are looking for\n" * 50)
    reader = RecordingReader(path)
    assert list(reader) == []
    assert reader.damage == "not an MCAP file (bad magic bytes)"


def test_unknown_topics_and_invalid_payloads_are_skipped_and_counted(tmp_path: Path) -> None:
    path = tmp_path / "foreign.mcap"
    good = sample_messages()[3][1].model_dump_json().encode()
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        other = writer.register_channel("/camera", message_encoding="json", schema_id=0)
        motor = writer.register_channel(key_expr(SW, "motor"), message_encoding="json", schema_id=0)
        for t, (channel, data) in enumerate([(other, b"{}"), (motor, b"{"), (motor, good)]):
            writer.add_message(channel, log_time=t, data=data, publish_time=t)
        writer.finish()
    reader = RecordingReader(path)
    assert [r.log_time_ns for r in reader] == [2]
    assert reader.skipped == {"unknown topic": 1, "not json": 1}
    assert reader.damage is None
