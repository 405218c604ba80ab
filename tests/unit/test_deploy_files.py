"""docker-compose.yml and the Dockerfile: parse, pin the router, and name only real commands."""
from __future__ import annotations

from importlib.metadata import version
from pathlib import Path

import pytest
import yaml

from railswitch.services.commands.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_compose_runs_router_simulator_diagnoser_and_recorder(compose):
    assert {"router", "simulator", "diagnoser", "recorder"} <= set(compose["services"])


def test_router_image_has_the_minor_version_of_the_zenoh_package(compose):
    image = compose["services"]["router"]["image"]
    name, _, tag = image.partition(":")
    assert name == "eclipse/zenoh"
    assert tag.split(".")[:2] == version("eclipse-zenoh").split(".")[:2]


@pytest.mark.parametrize("service", ["simulator", "diagnoser", "recorder"])
def test_every_service_command_parses_in_the_cli_and_connects_to_the_router(compose, service):
    command = compose["services"][service]["command"]
    args = build_parser().parse_args(command)  # exits (fails the test) on an unknown command or option
    assert (args.command, args.service) == ("serve", service)
    assert args.connect == ["tcp/router:7447"]


def test_notify_runs_on_its_profile_with_the_webhook_from_the_environment(compose):
    service = compose["services"]["notify"]
    assert service["profiles"] == ["notify"]  # a plain `docker compose up` needs no webhook
    command = [word.replace("${RAILSWITCH_WEBHOOK:?set RAILSWITCH_WEBHOOK, where alarm changes are POSTed}",
                            "https://alarms.example/railswitch") for word in service["command"]]
    assert command != service["command"]
    args = build_parser().parse_args(command)
    assert (args.command, args.service, args.connect, args.webhook) == ("serve", "notify", ["tcp/router:7447"], "https://alarms.example/railswitch")


def test_recording_goes_to_a_volume(compose):
    out = build_parser().parse_args(compose["services"]["recorder"]["command"]).out
    mounts = {volume.split(":")[1] for volume in compose["services"]["recorder"]["volumes"]}
    assert str(Path(out).parent) in mounts
    assert set(compose["volumes"]) >= {v.split(":")[0] for v in compose["services"]["recorder"]["volumes"]}


def test_dockerfile_installs_the_project_and_runs_railswitch():
    text = (ROOT / "Dockerfile").read_text()
    assert "pip install" in text and 'ENTRYPOINT ["railswitch"]' in text
    copied = {line.split()[1] for line in text.splitlines() if line.startswith("COPY")}
    assert {"models", "schemas", "services", "pyproject.toml"} <= copied


def test_router_config_file_is_mounted(compose):
    volumes = compose["services"]["router"]["volumes"]
    source = volumes[0].split(":")[0]
    assert (ROOT / source).is_file()
