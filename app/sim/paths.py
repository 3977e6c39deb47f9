"""Locations of the repository's bundled data (sample calibration)."""

from __future__ import annotations

from pathlib import Path

from app.geometry.calibration import StereoCalibration, paper_calibration

REPO_ROOT = Path(__file__).resolve().parents[2]


def default_calibration_path() -> Path | None:
    """``<repo>/sample_data/calibration.json`` if present, else None."""
    path = REPO_ROOT / "sample_data" / "calibration.json"
    return path if path.is_file() else None


def load_default_calibration() -> StereoCalibration:
    """The bundled sample calibration, or the paper's rig (Tables 1–2) if the file is missing."""
    path = default_calibration_path()
    if path is None:
        return paper_calibration()
    return StereoCalibration.load(path)
