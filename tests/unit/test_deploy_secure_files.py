"""docker-compose.secure.yml: parses, pins the router, runs real commands on TLS, and mounts every
file its Zenoh configs name (deploy/secure templates; secrets from the git-ignored ./secrets)."""
from __future__ import annotations

import json
import re
from importlib.metadata import version
from pathlib import Path, PurePosixPath

import pytest
import yaml
import zenoh

from railswitch.services.commands.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
TEMPLATES = ROOT / "deploy" / "secure"
SERVICES = ["simulator", "diagnoser", "recorder", "historian", "notify"]
EXAMPLE_ENV = {"RAILSWITCH_WEBHOOK": "https://alarms.example/railswitch"}  # what compose takes from the environment


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.secure.yml").read_text())


def mounts(compose: dict, service: str) -> dict[str, str]:
    """Container path -> host path of a service's bind mounts (named volumes left out)."""
    out = {}
    for volume in compose["services"][service].get("volumes", []):
        source, target = volume.split(":")[:2]
        if source.startswith("./"):
            out[target] = source[2:]
    return out


def template_of(source: str) -> Path:
    """The committed file a mounted config comes from: itself, or for secrets/<name>.json5 its template."""
    path = Path(source)
    return TEMPLATES / path.name if path.parts[0] == "secrets" else ROOT / path


def files_named_by(config: zenoh.Config) -> set[str]:
    tls = json.loads(config.get_json("transport/link/tls"))
    usrpwd = json.loads(config.get_json("transport/auth/usrpwd"))
    named = [tls[k] for k in ("root_ca_certificate", "listen_certificate", "listen_private_key",
                              "connect_certificate", "connect_private_key")] + [usrpwd["dictionary_file"]]
    return {path for path in named if path}


def interpolated(command: list[str]) -> list[str]:
    """A command as compose runs it: each ${NAME:?message} replaced by the environment's value (EXAMPLE_ENV)."""
    return [re.sub(r"\$\{(\w+):\?[^}]*\}", lambda m: EXAMPLE_ENV[m.group(1)], word) for word in command]


def test_compose_runs_router_simulator_diagnoser_recorder_historian_notify_and_the_history_database(compose):
    assert set(compose["services"]) == {"router", "postgres", *SERVICES}


def test_router_image_has_the_minor_version_of_the_zenoh_package(compose):
    name, _, tag = compose["services"]["router"]["image"].partition(":")
    assert name == "eclipse/zenoh"
    assert tag.split(".")[:2] == version("eclipse-zenoh").split(".")[:2]


def test_router_runs_the_secure_router_config(compose):
    command = compose["services"]["router"]["command"]
    assert command[0] == "-c"
    assert mounts(compose, "router")[command[1]] == "deploy/secure/router.json5"


@pytest.mark.parametrize("service", SERVICES)
def test_every_service_command_parses_and_uses_its_own_zenoh_config_over_tls(compose, service):
    args = build_parser().parse_args(interpolated(compose["services"][service]["command"]))  # exits on a bad option
    assert (args.command, args.service) == ("serve", service)
    assert args.connect == ["tls/router:7447"]
    assert mounts(compose, service)[args.zenoh_config] == f"secrets/{service}.json5"


@pytest.mark.parametrize("service", ["router", *SERVICES])
def test_every_mounted_config_comes_from_deploy_secure_and_loads(compose, service):
    configs = [source for source in mounts(compose, service).values() if source.endswith(".json5")]
    assert len(configs) == 1
    template = template_of(configs[0])
    assert template.parent == TEMPLATES
    zenoh.Config.from_file(str(template))


@pytest.mark.parametrize("service", ["router", *SERVICES])
def test_every_file_a_config_names_is_mounted_from_secrets(compose, service):
    bound = mounts(compose, service)
    config_source = next(source for source in bound.values() if source.endswith(".json5"))
    named = files_named_by(zenoh.Config.from_file(str(template_of(config_source))))
    assert named, "a secured config names its certificates and credentials"
    for path in named:
        assert PurePosixPath(bound[path]).parts[0] == "secrets", path


def test_router_listens_on_the_published_tls_port(compose):
    config = zenoh.Config.from_file(str(TEMPLATES / "router.json5"))
    assert json.loads(config.get_json("listen/endpoints")) == ["tls/0.0.0.0:7447"]
    assert "7447:7447" in compose["services"]["router"]["ports"]


def test_only_the_router_gets_a_private_key_and_none_gets_the_ca_key(compose):
    for service in compose["services"]:
        keys = {source for source in mounts(compose, service).values() if source.endswith("key.pem")}
        assert keys == ({"secrets/router-key.pem"} if service == "router" else set()), service


def test_secrets_are_ignored_by_git():
    assert "/secrets/" in (ROOT / ".gitignore").read_text().split()


def test_credentials_example_has_a_line_per_user_with_a_placeholder_password():
    lines = (TEMPLATES / "credentials.txt.example").read_text().split()
    users = {name.removesuffix(".json5") for name in (p.name for p in TEMPLATES.glob("*.json5"))} - {"router"}
    assert {line.split(":")[0] for line in lines} == users
    assert {line.split(":", 1)[1] for line in lines} == {"REPLACE-WITH-A-RANDOM-PASSWORD"}
