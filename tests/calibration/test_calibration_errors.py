"""Bad checkerboard sets give documented one-line errors (CLI exit code 2), never a traceback."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.calibration.board import Board, CheckerboardError, pair_name, parse_board
from app.calibration.detection import PairDetection, check_image_sizes
from app.calibration.stereo_calibration import calibrate_from_detections
from app.cli.main import main

REPO = Path(__file__).resolve().parents[2]
SET_DIR = REPO / "sample_data" / "checkerboard"
PREFIX = "aar-dock calibrate: error: "


def _copy_pairs(dest: Path, indices) -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    for k in indices:
        for side in ("left", "right"):
            shutil.copy(SET_DIR / f"{side}_{k:02d}.png", dest / f"{side}_{k:02d}.png")
    return dest


def _run(capsys, folder: Path, *extra: str) -> tuple[int, str, str]:
    code = main(
        [
            "calibrate",
            "--left",
            str(folder / "left_*.png"),
            "--right",
            str(folder / "right_*.png"),
            "--out",
            str(folder / "out" / "calibration.json"),
            "--no-progress",
            *extra,
        ]
    )
    out, err = capsys.readouterr()
    return code, out, err


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith(PREFIX), err
    assert "Traceback" not in err
    return lines[0][len(PREFIX) :]


def test_three_views_is_too_few(tmp_path, capsys):
    folder = _copy_pairs(tmp_path / "set", range(3))
    code, _, err = _run(capsys, folder)
    assert code == 2
    msg = _one_error_line(err)
    assert msg.startswith("too few usable views: only 3 pairs given, need at least 6")
    assert not (folder / "out" / "calibration.json").exists()


def test_three_views_console_script_exit_code(tmp_path):
    """The installed entry point, as a user runs it: exit status 2, one line on stderr."""
    folder = _copy_pairs(tmp_path / "set", range(3))
    proc = subprocess.run(
        [sys.executable, "-m", "app.cli.main", "calibrate", "--left", str(folder / "left_*.png"),
         "--right", str(folder / "right_*.png"), "--out", str(tmp_path / "c.json"), "--no-progress"],
        capture_output=True, text=True, cwd=REPO, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert _one_error_line(proc.stderr).startswith("too few usable views")


def test_mismatched_image_sizes(tmp_path, capsys):
    folder = _copy_pairs(tmp_path / "set", range(6))
    img = cv2.imread(str(folder / "right_04.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(folder / "right_04.png"), cv2.resize(img, (640, 512)))
    code, _, err = _run(capsys, folder)
    assert code == 2
    msg = _one_error_line(err)
    assert msg == (
        "image sizes differ: right image of pair 04 is 640x512 px, the first left image is 1280x1024 px"
    )


def test_board_size_that_does_not_match(tmp_path, capsys):
    """The classic mistake: counting squares (10x7) instead of inner corners (9x6)."""
    folder = _copy_pairs(tmp_path / "set", range(6))
    code, _, err = _run(capsys, folder, "--board", "10x7")
    assert code == 2
    msg = _one_error_line(err)
    assert "0 of 6 pairs" in msg
    assert "board size does not match" in msg and "9x6" in msg


def test_boards_not_found(tmp_path, capsys):
    """Pictures without any board: no usable views, and no board size to suggest."""
    folder = tmp_path / "blank"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(6):
        for side in ("left", "right"):
            img = np.clip(rng.normal(100, 5, (512, 640)), 0, 255).astype(np.uint8)
            cv2.imwrite(str(folder / f"{side}_{k:02d}.png"), img)
    code, _, err = _run(capsys, folder)
    assert code == 2
    msg = _one_error_line(err)
    assert "0 of 6 pairs" in msg and "6 board not found in either image" in msg


def test_one_sided_pair_is_rejected_and_reported(tmp_path, capsys):
    folder = _copy_pairs(tmp_path / "set", [1, 2, 3, 4, 6, 7, 9])
    blank = np.full((1024, 1280), 95, np.uint8)
    cv2.imwrite(str(folder / "right_03.png"), blank)
    report = tmp_path / "report"
    code, out, err = _run(capsys, folder, "--report", str(report))
    assert code == 0, err
    assert "warning: pair 03 rejected: board found in the left image only" in err
    assert "views used      6 of 7 (1 rejected)" in out
    data = json.loads((report / "report.json").read_text())
    assert data["report"]["rejected"] == [
        {"name": "03", "reason": "board found in the left image only"}
    ]
    assert [v["name"] for v in data["report"]["views"]] == ["01", "02", "04", "06", "07", "09"]
    assert (report / "report.png").stat().st_size > 10_000
    saved = json.loads((folder / "out" / "calibration.json").read_text())
    assert saved["left"]["K"][0][1] == 0.0 and saved["units"] == "mm"


def test_no_files_and_count_mismatch(tmp_path, capsys):
    code, _, err = _run(capsys, tmp_path / "nothing")
    assert code == 2 and "no files match --left" in _one_error_line(err)
    folder = _copy_pairs(tmp_path / "set", range(2))
    (folder / "right_01.png").unlink()
    code, _, err = _run(capsys, folder)
    assert code == 2 and "2 left images but 1 right images" in _one_error_line(err)


def test_unreadable_image_and_bad_board_argument(tmp_path, capsys):
    folder = _copy_pairs(tmp_path / "set", range(1))
    (folder / "left_00.png").write_bytes(b"not a png")
    code, _, err = _run(capsys, folder)
    assert code == 2 and "cannot read image" in _one_error_line(err)
    folder2 = _copy_pairs(tmp_path / "set2", range(1))
    for bad, expected in (
        ("9by6", "expected COLSxROWS"),
        ("6x6", "ambiguous"),
        ("2x5", "at least 3x3"),
    ):
        code, _, err = _run(capsys, folder2, "--board", bad)
        assert code == 2 and expected in _one_error_line(err)
    code, _, err = _run(capsys, folder2, "--square-mm", "-3")
    assert code == 2 and "positive" in _one_error_line(err)


def test_core_errors_are_value_errors():
    with pytest.raises(CheckerboardError, match="expected COLSxROWS"):
        parse_board("nine by six")
    assert parse_board(" 9 x 6 ") == (9, 6)
    assert issubclass(CheckerboardError, ValueError)
    a = np.zeros((10, 12), np.uint8)
    with pytest.raises(CheckerboardError, match="2 left images but 1 right images"):
        check_image_sizes(["a", "b"], [a, a], [a])
    with pytest.raises(
        CheckerboardError, match="image sizes differ: left image of pair b is 12x11"
    ):
        check_image_sizes(["a", "b"], [a, np.zeros((11, 12), np.uint8)], [a, a])
    dets = [PairDetection(str(k), (12, 10), None, None) for k in range(4)]
    with pytest.raises(CheckerboardError, match="too few usable views: 0 of 4"):
        calibrate_from_detections(dets, Board(9, 6, 25.0))
    pts = np.zeros((54, 2))
    dets = [PairDetection(str(k), (12, 10), pts, pts) for k in range(5)]
    dets.append(PairDetection("5", (12, 10), pts, None))
    with pytest.raises(
        CheckerboardError,
        match=r"too few usable views: 5 of 6 pairs .* need at least 6 \(1 board found in the left image only\)",
    ):
        calibrate_from_detections(dets, Board(9, 6, 25.0))
    with pytest.raises(CheckerboardError, match="model 'fisheye'"):
        calibrate_from_detections(dets, Board(9, 6, 25.0), model="fisheye")


def test_pair_names():
    assert pair_name("left_03.png", "right_03.png") == "03"
    assert pair_name("L7.png", "R7.png") == "7"
    assert pair_name("img_a.png", "img_b.png") == "img_a|img_b"
