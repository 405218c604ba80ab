"""docker-compose.yml's historian: a real command that connects to the router, its file on a volume."""
from pathlib import Path

import yaml

from railswitch.services.commands.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]


def test_the_historian_service_keeps_its_file_on_a_volume_and_connects_to_the_router():
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    historian = compose["services"]["historian"]
    args = build_parser().parse_args(historian["command"])  # exits (fails the test) on an unknown option
    assert args.command == "historian" and args.connect == ["tcp/router:7447"]
    mounts = {volume.split(":")[1]: volume.split(":")[0] for volume in historian["volumes"]}
    assert str(Path(args.db).parent) in mounts and mounts[str(Path(args.db).parent)] in compose["volumes"]
    assert historian["stop_signal"] == "SIGTERM"
