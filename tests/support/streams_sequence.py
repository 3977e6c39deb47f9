"""A rendered stereo sequence with truth, written as MJPG videos and PNG folders (stream tests)."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from app.geometry.calibration import StereoCalibration
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import render_pair

FPS = 30.0


@dataclass
class Sequence:
    calib: StereoCalibration
    lefts: list[np.ndarray]
    rights: list[np.ndarray]
    led_xyz_mm: list[np.ndarray]  # truth per frame, (5, 3) rows for ids 1..5
    centers_mm: list[np.ndarray]


def render_sequence(calib: StereoCalibration, n: int = 40, depth_mm: float = 1000.0) -> Sequence:
    """The drogue closing at 0.45 m/s (15 mm/frame at 30 fps) while drifting and rolling."""
    seq = Sequence(calib, [], [], [], [])
    x0 = stereo_center_x_mm(calib, depth_mm)
    for i in range(n):
        centre = np.array([x0 + 3.0 * i, -20.0 + 1.5 * i, depth_mm + 300.0 - 15.0 * i])
        pair = render_pair(calib, centre, tilted_normal(6.0, 30.0 + i), seed=i, roll_rad=0.02 * i)
        seq.lefts.append(pair.left)
        seq.rights.append(pair.right)
        seq.led_xyz_mm.append(pair.truth.led_xyz_mm)
        seq.centers_mm.append(centre)
    return seq


def write_avi(seq: Sequence, directory: Path, quality: float = 100.0) -> tuple[Path, Path]:
    paths = []
    w, h = seq.calib.image_size
    for side, images in (("left", seq.lefts), ("right", seq.rights)):
        path = directory / f"{side}.avi"
        vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (w, h), False)
        assert vw.isOpened()
        vw.set(cv2.VIDEOWRITER_PROP_QUALITY, quality)
        for img in images:
            vw.write(img)
        vw.release()
        paths.append(path)
    return paths[0], paths[1]


def write_png_folders(
    seq: Sequence, directory: Path, timestamps: bool = False
) -> tuple[Path, Path]:
    paths = []
    for side, images in (("left", seq.lefts), ("right", seq.rights)):
        d = directory / side
        d.mkdir(parents=True)
        for i, img in enumerate(images):
            cv2.imwrite(str(d / f"{i:04d}.png"), img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if timestamps:
            (d / "timestamps.txt").write_text(
                "\n".join(f"{i / FPS:.6f}" for i in range(len(images)))
            )
        paths.append(d)
    return paths[0], paths[1]


def led_errors_mm(rows: list[dict], seq: Sequence) -> list[float]:
    """Per locked frame: the largest LED 3-D error (mm) against the truth of its id."""
    out = []
    for row in rows:
        if not row["lock"]:
            continue
        truth = seq.led_xyz_mm[row["frame"]]
        err = max(
            float(np.linalg.norm(np.subtract(led["xyz_mm"], truth[led["id"] - 1])))
            for led in row["leds"]
        )
        out.append(err)
    return out


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@functools.cache
def cached_sequence(n: int = 40) -> Sequence:
    """One rendering per test session (the sample calibration)."""
    from app.resources import load_default_calibration

    return render_sequence(load_default_calibration(), n)
