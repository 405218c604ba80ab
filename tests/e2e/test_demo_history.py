"""The demo with its historian: the recording holds health, the history file next to it holds every diagnosis
and health message, the summary shows each switch's health, and the shipped Foxglove layout names only topics
and fields that such a recording has."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest
from mcap.reader import make_reader

from railswitch.schemas import HISTORY_KINDS, json_schema, SwitchHealth
from railswitch.services.adapters.history_db import HistoryDb
from tests.live import ROOT

LAYOUT = ROOT / "deploy" / "foxglove" / "railswitch-layout.json"
# The part of Foxglove's message path syntax the layout uses: .field, [:] and {field=="text"}
# (https://docs.foxglove.dev/docs/visualization/message-path-syntax).
PATH_PART = re.compile(r'\.(?P<field>[A-Za-z0-9_]+)|(?P<all>\[:\])|\{(?P<key>[A-Za-z0-9_]+)=="(?P<value>[^"]*)"\}')
TOPIC = re.compile(r"[A-Za-z0-9_-]+(/[A-Za-z0-9_-]+)*")


@dataclass(frozen=True)
class DemoRun:
    output: str
    recording: Path
    history: Path
    messages: dict[str, list[dict]]  # per topic, as the official mcap reader gives them
    schemas: dict[str, str]  # per topic


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> DemoRun:
    work = tmp_path_factory.mktemp("demo")
    recording = work / "demo.mcap"
    result = subprocess.run([sys.executable, "-m", "railswitch", "demo", "--switches", "2", "--throws", "3",
                             "--speed", "20", "--out", str(recording)], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    messages: dict[str, list[dict]] = {}
    schemas: dict[str, str] = {}
    with open(recording, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            messages.setdefault(channel.topic, []).append(json.loads(message.data))
            schemas[channel.topic] = schema.data.decode()
    return DemoRun(result.stdout, recording, recording.with_suffix(".sqlite"), messages, schemas)


def test_the_recorder_records_every_switchs_health(demo):
    for switch_id in ("sw1", "sw2"):
        topic = f"railswitch/{switch_id}/health"
        assert len(demo.messages[topic]) == len(demo.messages[f"railswitch/{switch_id}/diagnosis"]) == 3
        assert demo.schemas[topic] == json_schema(SwitchHealth)


def test_the_demos_history_file_next_to_its_recording_holds_what_the_recording_holds(demo):
    def index(message: dict) -> int:  # a throw's, or an alarm change's number
        return message["throw_index"] if "throw_index" in message else message["sequence"]

    recorded = Counter((topic.split("/")[1], topic.split("/")[2], index(m))
                       for topic, messages in demo.messages.items() if topic.split("/")[2] in HISTORY_KINDS
                       for m in messages)
    with HistoryDb(demo.history, create=False) as db:
        kept = Counter((s, kind, index(json.loads(payload))) for s in db.switches() for kind in HISTORY_KINDS
                       for payload in db.latest(s, kind, None, None, 1000)[0])
    assert kept == recorded
    assert sum(n for (_, kind, _), n in kept.items() if kind != "alarm") == 2 * 2 * 3


def test_the_demo_summary_shows_each_switchs_health(demo):
    table = demo.output[demo.output.index("health of each switch after its last throw"):]
    for switch_id in ("sw1", "sw2"):
        assert re.search(rf"│ {switch_id}\s+│ 2\s+│ (ok|watch|alarm)\s+│", table), table
    assert f"history: {demo.history}" in demo.output


@pytest.mark.parametrize("source", ["recording", "history file"])
def test_report_draws_one_health_picture_per_switch_of_the_fleet_from_the_recording_or_the_history(demo, tmp_path,
                                                                                                   source):
    given = [str(demo.recording), "--model", "none"] if source == "recording" else ["--db", str(demo.history)]
    result = subprocess.run([sys.executable, "-m", "railswitch", "report", *given, "--out", str(tmp_path)],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    pictures = sorted(p.name for p in tmp_path.glob("*_health.png"))
    assert pictures == ["sw1_health.png", "sw2_health.png"]
    assert all((tmp_path / name).stat().st_size > 10_000 for name in pictures)


def layout_paths() -> list[str]:
    """Every message path the layout's panels name (plots, state transitions, raw messages)."""
    config = json.loads(LAYOUT.read_text())["configById"]
    paths = [p["value"] for panel in config.values() for p in panel.get("paths", [])]
    return paths + [panel["topicPath"] for panel in config.values() if "topicPath" in panel]


def values_at(message: dict, path: str) -> list:
    """What a message path after the topic gives for one message: every value it reaches."""
    values, position = [message], 0
    while position < len(path):
        part = PATH_PART.match(path, position)
        assert part is not None, f"unsupported message path syntax at {path[position:]!r}"
        position = part.end()
        if part["field"]:
            values = [v[part["field"]] for v in values if isinstance(v, dict) and part["field"] in v]
        elif part["all"]:
            values = [item for v in values if isinstance(v, list) for item in v]
        else:
            values = [v for v in values if isinstance(v, dict) and v.get(part["key"]) == part["value"]]
    return values


def test_the_foxglove_layout_names_only_topics_and_fields_a_demo_recording_has(demo):
    paths = layout_paths()
    assert {p.split(".")[0] for p in paths} >= {"railswitch/sw1/motor", "railswitch/sw1/diagnosis",
                                                "railswitch/sw1/health"}
    for path in paths:
        topic = TOPIC.match(path)[0]
        assert topic in demo.messages, f"{path}: no topic {topic} in the recording"
        reached = [v for message in demo.messages[topic] for v in values_at(message, path[len(topic):])]
        assert reached, f"{path}: no message of {topic} has this field"
        assert path == topic or all(isinstance(v, (int, float, str)) for v in reached if v is not None), path
