"""`railswitch calibrate`: calibrate the reduced models against the plant over the population: the
bearing-fault port, what a healthy switch's fit leaves, the model's error on each fault parameter, and the false
alarms on held-out healthy switches (exit code 1 when they exceed the limit; a failing calibration never replaces
the shipped model)."""
from __future__ import annotations

import argparse
import sys

from railswitch.models.plant.reference import DIRECTIONS
from railswitch.schemas.faults import FAULT_PARAMETERS
from railswitch.services.commands.options import add_model_argument, fail, models_named
from railswitch.services.model_jobs import CheckFailed, calibrate_and_save, check_summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_model_argument(parser, "all", default="all")
    parser.add_argument("--replace-shipped", action="store_true",
                        help="store the port in the weights shipped inside the installed package "
                             "(default: the user's model directory, $RAILSWITCH_MODELS)")
    parser.add_argument("--check-only", action="store_true",
                        help="only count the false alarms of the stored calibration on held-out healthy switches "
                             "(two to five minutes per model), and store the count beside it")


def run(args: argparse.Namespace) -> int:
    failed, refused = [], []
    try:
        for name in models_named(args.model):
            try:
                path, found = calibrate_and_save(name, replace_shipped=args.replace_shipped, check_only=args.check_only)
            except CheckFailed as error:  # the next models are still calibrated
                print(f"railswitch: {name}: calibration failed its check: {error}", file=sys.stderr)
                refused.append(name)
                continue
            check = check_summary(found["calibration"]["healthy_check"])
            if not found["calibration"]["healthy_check"]["passed"]:
                failed.append(name)
            if args.check_only:
                print(f"{name}: {check} -> {path}")
                continue
            port, errors = found["bearing_port"], found["calibration"]["error_model"]
            ports = ", ".join(f"{d.replace('_', ' ')}: gain {port[d]['gain']:.4f}, offset {port[d]['offset_s_m']:.1f} N·s/m"
                              for d in DIRECTIONS)
            model = ", ".join(f"{n} bias {errors['bias'][n]:+.3g} {FAULT_PARAMETERS[n].unit} {errors['bias_relative'][n]:+.1%}, "
                              f"std {errors['absolute'][n]:.3g} {FAULT_PARAMETERS[n].unit} + {errors['relative'][n]:.1%} "
                              f"over {errors['throws'][n]:g} throws, {errors['one_absolute'][n]:.3g} "
                              f"{FAULT_PARAMETERS[n].unit} + {errors['one_relative'][n]:.1%} over one"
                              + (f", unit {errors['unit_relative'][n]:.1%} in every throw"
                                 if n in errors.get("unit_relative", {}) else "")
                              for n in errors["absolute"])
            print(f"{name}: bearing port {ports}; model error {model}; {check} -> {path}")
    except OSError as error:
        return fail(f"cannot write the calibration: {error}")
    if failed:
        print(f"railswitch: {', '.join(failed)} failed the check on held-out healthy switches: a diagnosis with "
              f"{'this model' if len(failed) == 1 else 'these models'} will raise false alarms", file=sys.stderr)
        return 1
    return 1 if refused else 0
