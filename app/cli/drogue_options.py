"""``--drogue FILE`` and ``--ring-radius-mm`` for the sub-commands that look for a drogue
(``process``, ``track``, ``serve``): the profile of :mod:`app.vision.drogue`."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.vision.drogue import DrogueProfile, resolve_drogue


def add_drogue_options(p: argparse.ArgumentParser, default_note: str) -> None:
    p.add_argument(
        "--drogue",
        metavar="FILE",
        help="the drogue's profile: ring radius, LED count, LED angles, LED diameter and "
        f"colour as one JSON file (app/vision/drogue.py; default: {default_note})",
    )
    p.add_argument(
        "--ring-radius-mm",
        type=float,
        help="the drogue's ring radius (mm), replacing the profile's",
    )


def drogue_from_args(args: argparse.Namespace, default: DrogueProfile) -> DrogueProfile:
    """The profile the flags name (``DrogueProfileError`` for a bad file or radius)."""
    path: str | None = getattr(args, "drogue", None)
    return resolve_drogue(Path(path) if path else None, args.ring_radius_mm, default)
