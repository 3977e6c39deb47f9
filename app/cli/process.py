"""``aar-dock process LEFT RIGHT``: run the navigation pipeline on one stereo pair."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from app.cli.drogue_options import add_drogue_options, drogue_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "process",
        help="estimate the drogue pose from one stereo pair",
        description="Run the navigation pipeline on LEFT RIGHT, or on a bundled sample pair "
        "(--sample pair_1000mm; --list-samples names them).",
    )
    p.add_argument("left", nargs="?", help="left image (PNG/JPEG/BMP/TIFF)")
    p.add_argument("right", nargs="?", help="right image")
    p.add_argument(
        "--sample", metavar="NAME", help="a sample pair shipped with the package (pair_1000mm, ...)"
    )
    p.add_argument("--list-samples", action="store_true", help="print the bundled sample pairs")
    p.add_argument("--calib", help="calibration JSON (default: the bundled paper calibration)")
    p.add_argument("--json", action="store_true", help="print the result contract as JSON")
    p.add_argument("--matcher", choices=["epipolar", "paper"], default="epipolar")
    add_drogue_options(p, "the paper's 75 mm ring with five 5 mm green LEDs")
    p.add_argument("--leds", type=int, help="LEDs on the ring, replacing the profile's")
    p.add_argument(
        "--led-diameter-mm",
        type=float,
        help="LED size (for the appearance test), replacing the profile's",
    )
    p.add_argument("--threshold", default="auto", help="'auto', 'otsu' or a gray level 1..255")
    p.set_defaults(func=run)


def _summary(result) -> str:  # type: ignore[no-untyped-def]
    lines = []
    if result.lock:
        d = result.drogue
        lines.append(
            "LOCK  centre = ({:.2f}, {:.2f}, {:.2f}) mm   normal = ({:.4f}, {:.4f}, {:.4f})   "
            "radius = {:.2f} mm   rms = {:.3f} mm".format(
                *d.center_mm, *d.normal, d.radius_mm, d.rms_mm
            )
        )
    else:
        lines.append(f"NO LOCK: {result.reason}")
    for led in result.leds:
        lines.append(
            "  LED {}: L({:.2f}, {:.2f}) R({:.2f}, {:.2f}) px → ({:.2f}, {:.2f}, {:.2f}) mm  "
            "epi {:.3f} px  reproj {:.3f} px".format(
                led.id,
                *led.left_px,
                *led.right_px,
                *led.xyz_mm,
                led.epipolar_px,
                led.reprojection_px,
            )
        )
    lines.append(f"  total {result.timing_ms.total:.1f} ms")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from app.geometry.calibration import CalibrationError, StereoCalibration
    from app.resources import MissingDataError, load_default_calibration, sample_pair, sample_pairs
    from app.vision.drogue import PAPER_DROGUE, DrogueProfileError
    from app.vision.io import check_pair, read_image
    from app.vision.pipeline import NavigationPipeline, PipelineConfig
    from app.vision.preprocess import ImageError

    if args.list_samples:
        print("\n".join(sample_pairs()))
        return 0
    try:
        if args.sample is not None:
            if args.left or args.right:
                raise ValueError("give either LEFT RIGHT or --sample, not both")
            left_path, right_path = (str(p) for p in sample_pair(args.sample))
        elif args.left and args.right:
            left_path, right_path = args.left, args.right
        else:
            raise ValueError("give LEFT and RIGHT images, or --sample NAME (see --list-samples)")
        threshold: int | str = int(args.threshold) if args.threshold.isdigit() else args.threshold
        if threshold not in ("auto", "otsu") and not (
            isinstance(threshold, int) and 1 <= threshold <= 255
        ):
            raise ValueError(
                f"--threshold must be 'auto', 'otsu' or 1..255, got {args.threshold!r}"
            )
        calib = StereoCalibration.load(args.calib) if args.calib else load_default_calibration()
        left = read_image(left_path)
        right = read_image(right_path)
        check_pair(left, right, left_path, right_path)
        drogue = drogue_from_args(args, PAPER_DROGUE)
        if args.leds is not None:
            drogue = replace(drogue, led_count=args.leds, led_angles_deg=None)
        if args.led_diameter_mm is not None:
            drogue = replace(drogue, led_diameter_mm=args.led_diameter_mm)
        config = drogue.pipeline_config(
            PipelineConfig(threshold=threshold, matcher=args.matcher)  # type: ignore[arg-type]
        )
        result = NavigationPipeline(calib, config).process(left, right)
    except (
        CalibrationError,
        DrogueProfileError,
        ImageError,
        MissingDataError,
        ValueError,
    ) as exc:
        print(f"aar-dock process: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(result.model_dump_json(indent=2))
    else:
        print(_summary(result))
    return 0
