"""``aar-dock render``: write one synthetic stereo pair (left.png, right.png, truth.json)."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "render",
        help="render a synthetic stereo pair of the drogue LED ring with ground truth",
        description=(
            "Render the drogue's LED ring into both cameras of a calibrated rig and write "
            "left.png, right.png and truth.json (LED 3-D points and exact pixel centres)."
        ),
    )
    p.add_argument("--range-mm", type=float, required=True, help="drogue depth Z (mm)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--clutter", type=int, default=0, help="number of clutter glints")
    p.add_argument("--second-object", action="store_true", help="add a large elongated glint")
    p.add_argument("--tilt-deg", type=float, default=0.0, help="normal tilt from head-on (deg)")
    p.add_argument(
        "--tilt-azimuth-deg",
        type=float,
        default=0.0,
        help="image direction the normal tilts towards (0 = right, 90 = down; deg)",
    )
    p.add_argument("--roll-deg", type=float, default=0.0, help="ring roll about its axis (deg)")
    p.add_argument(
        "--offset-mm",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("DX", "DY"),
        help="lateral offset of the ring centre from the stereo centre line (mm)",
    )
    p.add_argument("--occlude", default="", help="LED ids hidden in both images, e.g. 2,4")
    p.add_argument("--noise-sigma", type=float, default=None, help="sensor noise (DN)")
    p.add_argument("--calib", default=None, help="calibration JSON (default: sample_data)")
    p.add_argument("--color", action="store_true", help="write BGR images (green LEDs)")
    p.add_argument("--out", required=True, help="output directory (created)")
    p.set_defaults(func=run)


def _fail(message: str) -> int:
    print(f"aar-dock render: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    import json
    import math
    from dataclasses import asdict
    from pathlib import Path

    import cv2
    import numpy as np

    from app.geometry.calibration import CalibrationError, StereoCalibration
    from app.resources import default_calibration_path, load_default_calibration
    from app.sim.led_ring import LedRing, stereo_center_x_mm, tilted_normal
    from app.sim.stereo_render import RenderSettings, render_pair

    try:
        occluded = tuple(int(t) for t in args.occlude.split(",") if t.strip())
    except ValueError:
        return _fail(f"--occlude must be comma-separated LED ids, got {args.occlude!r}")
    if not (math.isfinite(args.range_mm) and args.range_mm > 0):
        return _fail(f"--range-mm must be a positive number, got {args.range_mm}")
    if args.clutter < 0:
        return _fail(f"--clutter must be >= 0, got {args.clutter}")
    if not (math.isfinite(args.tilt_deg) and abs(args.tilt_deg) < 90):
        return _fail(f"--tilt-deg must be in (-90, 90), got {args.tilt_deg}")
    try:
        if args.calib is not None:
            calib = StereoCalibration.load(args.calib)
            calib_name = str(args.calib)
        else:
            calib = load_default_calibration()
            path = default_calibration_path()
            calib_name = str(path) if path is not None else "paper_calibration()"
    except CalibrationError as exc:
        return _fail(str(exc))

    kwargs: dict[str, Any] = {
        "clutter": args.clutter,
        "second_object": args.second_object,
        "occluded": occluded,
        "color": args.color,
    }
    if args.noise_sigma is not None:
        kwargs["noise_sigma"] = args.noise_sigma
    ring = LedRing()
    try:
        settings = RenderSettings(**kwargs)
        x_mid = stereo_center_x_mm(calib, args.range_mm)
        center = np.array([x_mid + args.offset_mm[0], args.offset_mm[1], args.range_mm])
        normal = tilted_normal(args.tilt_deg, args.tilt_azimuth_deg)
        pair = render_pair(
            calib,
            center,
            normal,
            settings,
            ring,
            seed=args.seed,
            roll_rad=math.radians(args.roll_deg),
        )
    except ValueError as exc:
        return _fail(str(exc))

    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return _fail(f"cannot create {out}: {exc}")
    for name, img in (("left.png", pair.left), ("right.png", pair.right)):
        if not cv2.imwrite(str(out / name), img, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            return _fail(f"cannot write {out / name}")
    doc = pair.truth.to_dict()
    doc.update(
        {
            "seed": args.seed,
            "settings": settings.to_dict(),
            "ring": asdict(ring),
            "calibration": calib_name,
            "image_size": list(calib.image_size),
            "units": {"xyz": "mm", "px": "distorted pixels (u right, v down)"},
        }
    )
    (out / "truth.json").write_text(json.dumps(doc, indent=2) + "\n")
    n_vis = int(pair.truth.visible.sum())
    print(f"wrote {out}/left.png, right.png, truth.json ({n_vis}/{ring.count} LEDs visible)")
    return 0
