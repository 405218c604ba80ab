"""`railswitch train`: refit the reduced rail models on high-fidelity plant data."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

from railswitch.models.reduced.training import STAGE_ITERATIONS
from railswitch.services.commands.options import add_model_argument, bounded, fail, models_named
from railswitch.services.model_jobs import train_and_save


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_model_argument(parser, "all", default="all")
    parser.add_argument("--seed", type=bounded(int, 0, 2**32 - 1), default=0)
    parser.add_argument("--iterations", type=bounded(int, 1, 1000), default=STAGE_ITERATIONS,
                        help="Levenberg-Marquardt iterations per fitting stage")
    parser.add_argument("--threads", type=bounded(int, 1, 256), default=None,
                        help="threads that share the training data (default: one per core; the weights are the same)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--out", default=None, metavar="DIR",
                       help="where to write <model>.json, created if missing (default: the user's model directory, "
                            "$RAILSWITCH_MODELS)")
    where.add_argument("--replace-shipped", action="store_true",
                       help="overwrite the weights shipped inside the installed package")


def prepare_out_dir(out: str) -> str | None:
    """Make --out DIR ready before any training (it takes minutes): created with its parents if missing. The one
    line that says why it cannot be used, else None."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        return (f"--out {out} exists and is not a directory (give a directory for <model>.json; one is created if "
                "missing)")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        return f"--out {out}: cannot create the directory ({error.strerror or error})"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"--out {out}: the directory is not writable (give one you can write to)"
    return None


def run(args: argparse.Namespace) -> int:
    if args.out is not None and (problem := prepare_out_dir(args.out)):
        return fail(problem)
    try:
        for name in models_named(args.model):
            path, seconds = train_and_save(name, seed=args.seed, iterations=args.iterations, out_dir=args.out,
                                           replace_shipped=args.replace_shipped, threads=args.threads)
            print(f"trained {name} in {seconds:.1f} s: {path} (then `railswitch calibrate --model {name}`)")
    except OSError as error:
        return fail(f"cannot write the parameters: {error}")
    return 0
