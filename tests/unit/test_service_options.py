"""The live services' pure parts: scenarios, shards, session config, replay plans, command-line errors."""
from __future__ import annotations

import json
from collections import Counter

import pytest

from railswitch.schemas import MotorSample, ThrowEvent, key_expr
from railswitch.schemas.scenario import Scenario, ScenarioError, SwitchPlan, load_scenario
from railswitch.schemas import DEFAULT_ENDPOINT
from railswitch.services.adapters.zenoh_bus import BusError, BusOptions, zenoh_config
from railswitch.services.core.shards import in_shard, parse_shard
from railswitch.services.adapters.recordings import RecordedMessage
from railswitch.services.core.replay_plan import ReplayPlan


def test_scenario_steps_bearing_friction_every_throw_and_sets_an_obstacle_once():
    plan = SwitchPlan(id="sw1", throws=6, changes=[
        {"throw": 1, "until": 3, "add": {"bearing_friction": 1000.0}},
        {"throw": 4, "set": {"obstacle_friction": 1e5, "obstacle_position": 1.1}},
        {"throw": 5, "reset": True, "set": {"left_bolt_offset": 0.05}},
    ])
    schedule = plan.schedule()
    assert [f.get("bearing_friction", 0.0) for f in schedule] == [0.0, 1000.0, 2000.0, 3000.0, 3000.0, 0.0]
    assert schedule[4]["obstacle_friction"] == 1e5
    assert schedule[5] == {"left_bolt_offset": 0.05}


def test_scenario_rejects_degradation_that_leaves_the_fault_range():
    with pytest.raises(ValueError, match="bearing_friction=12000 is outside the accepted range"):
        Scenario(switches=[SwitchPlan(id="sw1", throws=4, changes=[{"throw": 0, "until": 3,
                                                                    "add": {"bearing_friction": 3000.0}}])])


@pytest.mark.parametrize("text, message", [
    ("interval_s = 5\n[[switches]]\nid='a'\nthrows=1", "interval_s 5 must exceed a throw's length"),
    ("[[switches]]\nid='a b'\nthrows=1", "switches.0.id"),
    ("[[switches]]\nid='a'\nthrows=1\nfaults={left_bolt_offset=0.5}", "left_bolt_offset=0.5 is outside"),
    ("[[switches]]\nid='a'\nthrows=1\n[[switches]]\nid='a'\nthrows=2", "switch ids repeat"),
    ("switches = [", "is not valid TOML"),
])
def test_a_bad_scenario_file_gives_one_line_naming_the_problem(tmp_path, text, message):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=message) as error:
        load_scenario(path)
    assert "\n" not in str(error.value)


def test_shards_split_a_fleet_of_100_evenly_and_stably():
    ids = [f"sw{k}" for k in range(100)]
    owners = [[parse_shard(f"{k}/2") for k in (1, 2) if in_shard(i, parse_shard(f"{k}/2"))] for i in ids]
    assert all(len(o) == 1 for o in owners)  # every switch in exactly one shard
    sizes = Counter(o[0] for o in owners)
    assert min(sizes.values()) >= 40
    assert in_shard("sw1", (1, 2)) == in_shard("sw1", (1, 2))


@pytest.mark.parametrize("text", ["0/2", "3/2", "1", "a/b", "1/0"])
def test_bad_shard_is_refused(text):
    with pytest.raises(ValueError):
        parse_shard(text)


def test_client_config_connects_to_the_local_router_without_multicast_by_default():
    config = zenoh_config(BusOptions())
    assert json.loads(config.get_json("mode")) == "client"
    assert json.loads(config.get_json("connect/endpoints")) == [DEFAULT_ENDPOINT]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def test_config_file_is_read_and_flags_override_it(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text('{ mode: "peer", connect: { endpoints: ["tcp/10.0.0.1:7447"] }, scouting: { multicast: { enabled: true } } }')
    from_file = zenoh_config(BusOptions(config_file=str(path)))
    assert json.loads(from_file.get_json("mode")) == "peer"
    assert json.loads(from_file.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447"]
    assert json.loads(from_file.get_json("scouting/multicast/enabled")) is False
    flagged = zenoh_config(BusOptions(config_file=str(path), mode="client", connect=("tcp/127.0.0.1:9",)))
    assert json.loads(flagged.get_json("mode")) == "client"
    assert json.loads(flagged.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]


def test_missing_config_file_is_a_one_line_bus_error(tmp_path):
    with pytest.raises(BusError, match="cannot read Zenoh config"):
        zenoh_config(BusOptions(config_file=str(tmp_path / "absent.json5")))


def _record(message) -> RecordedMessage:
    kind = "motor" if isinstance(message, MotorSample) else "throw"
    return RecordedMessage(key_expr("sw1", kind), kind, "sw1", message, message.t_ns)


def test_replay_loops_continue_time_sample_and_throw_numbers():
    profile = {"reference_t_s": [0.0, 1.0], "reference_velocity_rad_s": [0.0, 0.0]}
    messages = [MotorSample(switch_id="sw1", seq=k, t_ns=k * 20_000_000, current_a=0, angle_rad=0, velocity_rad_s=0)
                for k in range(3)]
    start = ThrowEvent(switch_id="sw1", throw_index=0, direction="left_to_right", phase="start", t_ns=0, **profile)
    plan = ReplayPlan.of([_record(m) for m in [messages[0], start, *messages[1:]]], ("motor", "throw"))
    passes = list(plan.passes(2))
    assert len(passes) == 8
    second = [m for _, _, m in passes[4:]]
    assert [m.seq for m in second if isinstance(m, MotorSample)] == [3, 4, 5]
    assert [m.t_ns for m in second if isinstance(m, MotorSample)] == [60_000_000, 80_000_000, 100_000_000]
    assert [m.throw_index for m in second if isinstance(m, ThrowEvent)] == [1]
