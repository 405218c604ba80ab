"""The historian of docker-compose.yml and of docker-compose.secure.yml: a real command that connects to the router
and writes the PostgreSQL service's database, whose data lies on a volume and whose password comes from the
environment, never from the file."""
from pathlib import Path

import pytest
import yaml
from psycopg.conninfo import conninfo_to_dict

from railswitch.services.commands.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
PASSWORD = "${RAILSWITCH_DB_PASSWORD:?set RAILSWITCH_DB_PASSWORD, the history database's password}"


COMPOSE = {"docker-compose.yml": "tcp/router:7447", "docker-compose.secure.yml": "tls/router:7447"}


@pytest.mark.parametrize("file, router", COMPOSE.items())
def test_the_historian_service_writes_the_postgres_services_database_and_connects_to_the_router(file, router):
    compose = yaml.safe_load((ROOT / file).read_text())
    historian = compose["services"]["historian"]
    args = build_parser().parse_args(historian["command"])  # exits (fails the test) on an unknown option
    assert (args.command, args.service) == ("serve", "historian") and args.connect == [router]
    target = conninfo_to_dict(args.db)
    assert args.db.startswith("postgresql://") and "password" not in target
    assert target["host"] == "postgres" and "postgres" in compose["services"]
    assert historian["depends_on"]["postgres"] == {"condition": "service_healthy"}
    assert historian["environment"]["PGPASSWORD"] == PASSWORD
    assert historian["stop_signal"] == "SIGTERM"


@pytest.mark.parametrize("file", COMPOSE)
def test_the_postgres_service_keeps_its_data_on_a_volume_checks_its_health_and_takes_its_password_from_outside(file):
    compose = yaml.safe_load((ROOT / file).read_text())
    postgres = compose["services"]["postgres"]
    assert postgres["image"] == "postgres:15"
    mounts = {volume.split(":")[1]: volume.split(":")[0] for volume in postgres["volumes"]}
    assert mounts["/var/lib/postgresql/data"] in compose["volumes"]
    assert "pg_isready" in " ".join(postgres["healthcheck"]["test"])
    assert postgres["environment"]["POSTGRES_PASSWORD"] == PASSWORD
    assert "ports" not in postgres  # reached on the compose network only
    user = conninfo_to_dict(build_parser().parse_args(compose["services"]["historian"]["command"]).db)["user"]
    assert postgres["environment"]["POSTGRES_USER"] == user
