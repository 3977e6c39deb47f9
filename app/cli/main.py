"""``aar-dock`` command line: one sub-command per module in :mod:`app.cli`."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

# Each module defines ``register(subparsers)`` which adds its parser and sets ``func``.
SUBCOMMANDS = (
    "process",
    "render",
    "simulate",
    "campaign",
    "calibrate",
    "serve",
    "track",
    "push",
    "export_mcap",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="aar-dock", description="Vision-based probe-and-drogue docking navigation (AAR)."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name in SUBCOMMANDS:
        module_name = f"app.cli.{name}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:
        # the reader went away (``aar-dock simulate | head``): not an error of ours. Point
        # stdout at devnull so that the interpreter's final flush does not raise again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1  # as Python's documentation suggests (signal module, "Note on SIGPIPE")
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
