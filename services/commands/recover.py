"""`railswitch recover F.mcap -o G.mcap`: what a damaged recording still holds, as a complete file."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from railswitch.services.adapters.recordings import recover_recording
from railswitch.services.commands.options import fail


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="F.mcap")
    parser.add_argument("-o", "--output", required=True, metavar="G.mcap")


def run(args: argparse.Namespace) -> int:
    if Path(args.output).resolve() == Path(args.recording).resolve():
        return fail("the recovered file must not replace the damaged one")
    try:
        recording = recover_recording(args.recording, args.output)
    except OSError as error:
        return fail(str(error) if error.strerror is None else f"cannot recover {args.recording}: {error.strerror}")
    note = recording.note() or "the file was intact"
    if not recording.records:
        print(f"railswitch recover: {args.recording}: {note}; nothing to recover", file=sys.stderr)
        return 1
    times = [record.log_time_ns for record in recording.records]
    print(f"recovered {len(recording.records)} messages spanning {(max(times) - min(times)) * 1e-9:.1f} s "
          f"into {args.output}: {note}")
    return 0
