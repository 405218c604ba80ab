"""`railswitch describe`: statistics of the plant and of each reduced model (states, parameters, ...)."""
from __future__ import annotations

import argparse
import json

from railswitch.services.adapters.compiled import compiled_plant
from railswitch.services.model_jobs import describe_reduced


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    description = {"plant": compiled_plant().describe(), "reduced": describe_reduced()}
    if args.json:
        print(json.dumps(description, indent=2, default=float))
        return 0
    print("plant")
    for key, value in description["plant"].items():
        print(f"  {key:24s} {value}")
    for name, stats in description["reduced"].items():
        print(f"reduced {name}")
        for key, value in stats.items():
            print(f"  {key:24s} {value}")
    return 0
