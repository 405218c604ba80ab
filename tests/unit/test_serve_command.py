"""`railswitch serve NAME` runs the long-running services; their own names stay as aliases (issue 41)."""
from __future__ import annotations

import pytest

from railswitch.services.commands.cli import COMMANDS, SERVICES, build_parser, main, named_command

pytestmark = pytest.mark.unit

EXAMPLES = {"router": ["--listen", "tcp/127.0.0.1:7999"], "simulator": ["--switches", "3"],
            "diagnoser": ["--model", "nn", "--shard", "2/3"], "recorder": ["--out", "x.mcap"],
            "historian": ["--db", "h.sqlite"], "notify": ["--webhook", "http://127.0.0.1:9/hook"]}


@pytest.mark.parametrize("name", SERVICES)
def test_serve_and_the_alias_take_the_same_arguments_to_the_same_service(name):
    served = build_parser(["serve", name]).parse_args(["serve", name, *EXAMPLES[name]])
    aliased = build_parser([name]).parse_args([name, *EXAMPLES[name]])
    assert served.handler is aliased.handler
    assert served.service == name and served.command == "serve"
    assert {k: v for k, v in vars(served).items() if k not in ("command", "service")} == \
        {k: v for k, v in vars(aliased).items() if k != "command"}


def test_only_the_service_asked_for_is_loaded():
    assert named_command(["serve", "--help"]) == []
    assert named_command(["serve", "-v", "historian", "--db", "diagnose.sqlite"]) == ["historian"]
    assert named_command(["diagnose", "history.mcap"]) == ["diagnose"]
    assert set(SERVICES) <= set(COMMANDS)


@pytest.mark.parametrize("argv, says", [(["serve"], "required: SERVICE"),
                                        (["serve", "diagnose"], "invalid choice: 'diagnose'"),
                                        (["serve", "diagnoser", "--shard", "9/2"], "9/2 is outside")])
def test_a_wrong_service_or_value_is_one_line_and_exit_2(argv, says, capsys):
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err and err.startswith("railswitch serve")
