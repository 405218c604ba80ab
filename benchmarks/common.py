"""Shared benchmark plumbing: one core, a JSON line printed last."""
from __future__ import annotations

import argparse
import json
import os


def pin_to_one_core() -> int:
    """Run on a single core, as the targets are stated; returns the core used."""
    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return core


def parser(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--json", action="store_true", help="print only the JSON result")
    return p


def emit(result: dict, as_json: bool) -> None:
    """Print the result; the JSON object is always the last line."""
    if not as_json:
        for key, value in result.items():
            print(f"{key:28s} {value}")
    print(json.dumps(result))
