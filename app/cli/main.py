"""``aar-dock`` command line: one sub-command per module in :mod:`app.cli`."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

# OpenCV reads its decoders' pixel limit (OPENCV_IO_MAX_IMAGE_PIXELS) once, when cv2 is first
# imported; the image guard sets it, so it runs before any sub-command module loads cv2
# (`aar-dock serve` then decodes under that limit as the service does in-process)
import app.service.image_guard  # noqa: F401, E402  (isort: keep before the sub-commands)

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
    "margins",
    "hose",
)


class CliParser(argparse.ArgumentParser):
    """Bad arguments: one line (``aar-dock SUB: error: ...``) and exit code 2, no usage
    block (``--help`` still prints it); the sub-commands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = CliParser(
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
    for sub_parser in sub.choices.values():  # its own errors name the sub-command
        sub_parser.set_defaults(cli_parser=sub_parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        getattr(args, "cli_parser", parser).error(f"unrecognized arguments: {' '.join(extra)}")
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
