"""Stereo calibration from checkerboard pairs (paper §3.2, Zhang's method): corner detection,
the rig check, the OpenCV fit, robust view dropping, skew refinement, the held-out check and
the report. Built on :mod:`app.geometry` (the camera model, projection, triangulation); the
geometry floor imports nothing from here.

The public entry points are re-exported here; each step lives in its own module.
"""

from app.calibration.board import Board, CheckerboardError, pair_name, parse_board
from app.calibration.detection import PairDetection, detect_pairs
from app.calibration.report import CalibrationReport
from app.calibration.report_plot import report_png_bytes, write_report_png
from app.calibration.stereo_calibration import (
    CheckerboardCalibration,
    calibrate_checkerboard,
    calibrate_from_detections,
)

__all__ = [
    "Board",
    "CalibrationReport",
    "CheckerboardCalibration",
    "CheckerboardError",
    "PairDetection",
    "calibrate_checkerboard",
    "calibrate_from_detections",
    "detect_pairs",
    "pair_name",
    "parse_board",
    "report_png_bytes",
    "write_report_png",
]
