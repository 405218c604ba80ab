"""Recordings written by other MCAP writers, with a newer publisher's payloads, diagnosed like our own (issue 17).

The source is a `railswitch simulate` recording. It is rewritten by the official Python mcap writer with other
chunk sizes and compressions, and by the TypeScript @mcap/core writer (tests/interchange/rewrite.mjs); both put
a field railswitch does not know into every motor, throw and truth payload, reorder the keys and add a /rosout
channel of another schema encoding. The payloads carry the same values, so `railswitch diagnose` must decide
and estimate every throw exactly as on the source: any difference is a reading fault, not a numerical one.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from railswitch.services.adapters.recordings import load_recording
from tests.interchange.foreign import EXTRA, EXTRA_KINDS, foreign_payload
from tests.live import ROOT

RAILSWITCH = [sys.executable, "-m", "railswitch"]
INTERCHANGE = ROOT / "tests" / "interchange"
ROSOUT_EVERY = 50  # a foreign log message after every 50 of ours, as rewrite.mjs does
ROSOUT_SCHEMA = b"builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\n"
ROSOUT_CDR = bytes([0, 1, 0, 0, 20, 0, 0, 0])  # a CDR header and a little of a log message: never decoded
REGISTRY_UNREACHABLE = re.compile(r"E(NOTFOUND|AI_AGAIN|CONNREFUSED|CONNRESET|TIMEDOUT|NETUNREACH)|network")


@dataclass(frozen=True)
class Diagnosed:
    """What `railswitch diagnose --jsonl` printed: every Diagnosis (without its latency) and its stderr."""

    diagnoses: list[dict]
    stderr: str


def diagnose(path: Path) -> Diagnosed:
    result = subprocess.run([*RAILSWITCH, "diagnose", str(path), "--jsonl"], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    rows = [json.loads(line) for line in result.stdout.splitlines() if line.strip()]
    for row in rows:
        row.pop("latency_ms")  # wall time, the one field allowed to differ
    return Diagnosed(rows, result.stderr)


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """Three throws of a switch with a 50 mm left bolt offset, with noise: small, and every throw a decision."""
    path = tmp_path_factory.mktemp("interchange") / "own.mcap"
    result = subprocess.run([*RAILSWITCH, "simulate", "--out", str(path), "--switch-id", "pm-4711", "--throws", "3",
                             "--fault", "left_bolt_offset=0.05", "--noise", "0.01", "--seed", "3"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return path


@pytest.fixture(scope="module")
def own(source: Path) -> Diagnosed:
    diagnosed = diagnose(source)
    assert len(diagnosed.diagnoses) == 3 and "ignored" not in diagnosed.stderr
    # What is compared are decisions and estimates, not three refusals.
    assert all(d["decision"] != "unknown" for d in diagnosed.diagnoses)
    assert any(d["estimate"] for d in diagnosed.diagnoses)
    return diagnosed


def kinds_in(path: Path) -> Counter[str]:
    """Messages per channel kind (the topic's last part), by the official reader."""
    with open(path, "rb") as f:
        return Counter(channel.topic.rsplit("/", 1)[-1] for _, channel, _ in make_reader(f).iter_messages())


def rewrite_with_python_mcap(source: Path, target: Path, *, chunk_size: int, compression: CompressionType) -> None:
    """source as another tool writes it with the official Python writer: its channels and schemas copied,
    payloads of a newer publisher (tests/interchange/foreign.py) and a /rosout channel between them."""
    with open(source, "rb") as f_in, open(target, "wb") as f_out:
        writer = Writer(f_out, chunk_size=chunk_size, compression=compression)
        writer.start(profile="", library="railswitch interchange test (mcap Python writer)")
        rosout = writer.register_channel("/rosout", "cdr", writer.register_schema("rcl_interfaces/msg/Log", "ros2msg",
                                                                                  ROSOUT_SCHEMA))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        messages = make_reader(f_in).iter_messages(log_time_order=False)
        for count, (schema, channel, message) in enumerate(messages, start=1):
            if channel.id not in channels:
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], dict(channel.metadata))
            data = foreign_payload(message.data) if channel.topic.rsplit("/", 1)[-1] in EXTRA_KINDS else message.data
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time, message.sequence)
            if count % ROSOUT_EVERY == 0:
                writer.add_message(rosout, message.log_time, ROSOUT_CDR, message.log_time, count)
        writer.finish()


def assert_chunks(path: Path, compression: str, chunk_size: int) -> None:
    """The file really is chunked and compressed as asked: every chunk but the last is full."""
    with open(path, "rb") as f:
        chunks = list(make_reader(f).get_summary().chunk_indexes)
    assert {chunk.compression for chunk in chunks} == {compression}
    assert all(chunk.uncompressed_size >= chunk_size for chunk in chunks[:-1])


def assert_read_like(source: Path, path: Path) -> None:
    """Our reader finds the source's messages, skips /rosout and counts the extra field per kind."""
    ours, theirs = load_recording(source), load_recording(path)
    kinds = kinds_in(source)
    assert theirs.records == ours.records and theirs.damage is None
    assert theirs.skipped == {"unknown topic": sum(kinds.values()) // ROSOUT_EVERY}
    assert theirs.ignored == {f"{kind}: {name}": kinds[kind] for kind in EXTRA_KINDS for name in EXTRA}


def assert_diagnosed_like(own: Diagnosed, other: Diagnosed, source: Path) -> None:
    """The same decisions and estimates, and one line on stderr naming what was skipped and ignored."""
    assert other.diagnoses == own.diagnoses
    kinds = kinds_in(source)
    note = [line for line in other.stderr.splitlines() if "ignored what this version does not know" in line]
    assert len(note) == 1, other.stderr
    assert f"skipped {sum(kinds.values()) // ROSOUT_EVERY} (unknown topic)" in note[0]
    assert f"motor: unit_serial ({kinds['motor']} messages)" in note[0]


CHUNK_SIZES = [4096, 1 << 20]
COMPRESSIONS = {CompressionType.ZSTD: "zstd", CompressionType.LZ4: "lz4", CompressionType.NONE: ""}


@pytest.mark.parametrize("chunk_size", CHUNK_SIZES, ids=["4KiB", "1MiB"])
@pytest.mark.parametrize("compression", COMPRESSIONS, ids=lambda c: c.name.lower())
def test_every_chunk_size_and_compression_of_the_python_writer_reads_back_to_our_messages(
        source, tmp_path, chunk_size, compression):
    path = tmp_path / "rewritten.mcap"
    rewrite_with_python_mcap(source, path, chunk_size=chunk_size, compression=compression)
    assert_chunks(path, COMPRESSIONS[compression], chunk_size)
    assert_read_like(source, path)


@pytest.mark.parametrize(("chunk_size", "compression"), [(4096, CompressionType.ZSTD), (1 << 20, CompressionType.LZ4),
                                                         (4096, CompressionType.NONE)], ids=["4KiB-zstd", "1MiB-lz4",
                                                                                             "4KiB-none"])
def test_a_recording_rewritten_by_the_official_python_writer_is_diagnosed_as_our_own(
        source, own, tmp_path, chunk_size, compression):
    path = tmp_path / "rewritten.mcap"
    rewrite_with_python_mcap(source, path, chunk_size=chunk_size, compression=compression)
    assert_diagnosed_like(own, diagnose(path), source)


# -- an independent implementation: the TypeScript @mcap/core writer ----------------------------------------------
@pytest.fixture(scope="session")
def node_rewriter(request, tmp_path_factory) -> list[str]:
    """The command running tests/interchange/rewrite.mjs, its packages installed by `npm ci` once per lock file
    into the pytest cache (a fresh folder without it). Skips only when node, npm or the registry is missing."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node and npm are needed to run the TypeScript MCAP writer (tests/interchange)")
    manifests = [INTERCHANGE / "package.json", INTERCHANGE / "package-lock.json"]
    digest = hashlib.sha256(b"".join(path.read_bytes() for path in manifests)).hexdigest()[:16]
    cache = getattr(request.config, "cache", None)
    root = Path(cache.mkdir("interchange-node")) if cache is not None else tmp_path_factory.mktemp("node")
    folder = root / digest
    if not folder.is_dir():
        _npm_ci(npm, manifests, root, folder)
    shutil.copy(INTERCHANGE / "rewrite.mjs", folder)
    return [node, str(folder / "rewrite.mjs")]


def _npm_ci(npm: str, manifests: list[Path], root: Path, folder: Path) -> None:
    """Install into a scratch folder and move it into place whole, so an interrupted install is never used."""
    scratch = root / f".{folder.name}.{os.getpid()}"
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir()
    for path in manifests:
        shutil.copy(path, scratch)
    result = subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--fetch-retries=1", "--fetch-timeout=30000"],
                            cwd=scratch, capture_output=True, text=True, timeout=600)
    if result.returncode != 0:
        shutil.rmtree(scratch, ignore_errors=True)
        unreachable = [line for line in result.stderr.splitlines() if REGISTRY_UNREACHABLE.search(line)]
        if unreachable:
            pytest.skip(f"the npm registry cannot be reached: {unreachable[0]}")
        pytest.fail(f"npm ci in tests/interchange failed:\n{result.stderr}")
    os.replace(scratch, folder)


def test_a_recording_rewritten_by_the_typescript_writer_is_diagnosed_as_our_own(source, own, node_rewriter, tmp_path):
    path = tmp_path / "typescript.mcap"
    result = subprocess.run([*node_rewriter, str(source), str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().library == "railswitch interchange test (@mcap/core)"
        summary = reader.get_summary()
        _, _, first = next(reader.iter_messages(topics=["railswitch/pm-4711/motor"]))
    assert {(c.topic, summary.schemas[c.schema_id].encoding) for c in summary.channels.values()
            if not c.topic.startswith("railswitch/")} == {("/rosout", "ros2msg")}
    with open(source, "rb") as f:
        _, _, ours = next(make_reader(f).iter_messages(topics=["railswitch/pm-4711/motor"]))
    assert list(json.loads(first.data)) == [*reversed(json.loads(ours.data)), *EXTRA]
    assert_chunks(path, "zstd", 4096)
    assert_read_like(source, path)
    assert_diagnosed_like(own, diagnose(path), source)


def test_the_typescript_rewriter_refuses_a_time_it_would_round(node_rewriter, tmp_path):
    """JavaScript numbers hold integers exactly only up to 2^53; live recordings' times (ns since 1970) are past it."""
    path = tmp_path / "live-time.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        channel = writer.register_channel("railswitch/sw1/motor", "json", 0)
        late = 1_700_000_000_000_000_001
        writer.add_message(channel, late, b'{"switch_id":"sw1","seq":0,"t_ns":%d,"current_a":0.0}' % late, late)
        writer.finish()
    result = subprocess.run([*node_rewriter, str(path), str(tmp_path / "out.mcap")], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 1
    assert "railswitch/sw1/motor.t_ns = 1700000000000000000 is past 2^53" in result.stderr
    assert not (tmp_path / "out.mcap").exists()
