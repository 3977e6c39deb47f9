"""``aar-dock process``: result contract on stdout, exit code 2 with one line on bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from app.cli.main import main
from app.resources import REPO_ROOT
from app.sim.stereo_render import render_pair


@pytest.fixture(scope="module")
def pair_dir(tmp_path_factory, calib):
    d = tmp_path_factory.mktemp("pair")
    normal = np.array([0.1, 0.0, -1.0]) / np.linalg.norm([0.1, 0.0, -1.0])
    pair = render_pair(calib, np.array([15.0, -10.0, 1100.0]), normal, seed=8)
    cv2.imwrite(str(d / "left.png"), pair.left)
    cv2.imwrite(str(d / "right.png"), pair.right)
    return d, pair.truth


def test_process_json_contract(pair_dir, capsys):
    d, truth = pair_dir
    assert main(["process", str(d / "left.png"), str(d / "right.png"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {
        "lock",
        "reason",
        "leds",
        "drogue",
        "timing_ms",
        "rejected_left_px",
        "rejected_right_px",
    }
    assert out["rejected_left_px"] == out["rejected_right_px"] == []  # a clean pair: none
    assert out["lock"] is True and out["reason"] is None
    assert set(out["drogue"]) == {
        "center_mm",
        "normal",
        "radius_mm",
        "rms_mm",
        "center_cov_mm2",
        "protection_level_mm",
        "fit_chi2",
        "fit_dof",
    }
    assert set(out["timing_ms"]) == {
        "preprocess",
        "extract",
        "describe",
        "match",
        "triangulate",
        "pose",
        "bound",
        "total",
    }
    assert len(out["leds"]) == 5
    assert set(out["leds"][0]) == {
        "id",
        "left_px",
        "right_px",
        "xyz_mm",
        "descriptor_distance",
        "epipolar_px",
        "reprojection_px",
        "sigma_px",
        "cov_mm2",
        "protection_level_mm",
    }
    err = np.linalg.norm(np.array(out["drogue"]["center_mm"]) - truth.center_mm)
    assert err < 0.5
    # the error bound: a 99.9 % protection level that holds and is not vacuous at 1.1 m
    assert err <= out["drogue"]["protection_level_mm"] < 5.0
    assert out["drogue"]["fit_dof"] == 9 and 0.0 <= out["drogue"]["fit_chi2"] < 30.0


def test_process_human_summary(pair_dir, capsys):
    d, _ = pair_dir
    assert main(["process", str(d / "left.png"), str(d / "right.png")]) == 0
    assert capsys.readouterr().out.startswith("LOCK")


def test_process_bad_inputs_exit_2_with_one_line(pair_dir, tmp_path, capsys):
    d, _ = pair_dir
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 120), np.uint8))
    bad_calib = tmp_path / "calib.json"
    bad_calib.write_text('{"image_size": [1280, 1024]}')
    cases = [
        ([str(d / "left.png"), str(tmp_path / "missing.png")], "missing.png"),
        ([str(corrupt), str(d / "right.png")], "corrupt.png"),
        ([str(d / "left.png"), str(small)], "small.png"),
        ([str(small), str(small)], "calibration is for 1280×1024"),
        ([str(d / "left.png"), str(d / "right.png"), "--calib", str(bad_calib)], "left"),
    ]
    for argv, needle in cases:
        assert main(["process", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err, err


SAMPLE_PAIRS = sorted(p.name for p in (REPO_ROOT / "sample_data").glob("pair_*"))


def test_there_are_sample_pairs():
    assert {"pair_0600mm", "pair_1000mm", "pair_2500mm", "pair_1000mm_clutter"} <= set(SAMPLE_PAIRS)


@pytest.mark.parametrize("name", SAMPLE_PAIRS)
def test_sample_pairs_give_their_truth(name, capsys):
    d = REPO_ROOT / "sample_data" / name
    truth = json.loads((d / "truth.json").read_text())
    assert main(["process", str(d / "left.png"), str(d / "right.png"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["lock"], out["reason"]
    tol_mm = 0.5 if "2500" not in name else 2.0
    assert np.linalg.norm(np.array(out["drogue"]["center_mm"]) - truth["center_mm"]) < tol_mm
    for led in out["leds"]:
        assert (
            np.linalg.norm(np.array(led["xyz_mm"]) - truth["led_xyz_mm"][led["id"] - 1])
            < 2 * tol_mm
        )


def test_sample_option_uses_the_bundled_pair(capsys):
    assert main(["process", "--list-samples"]) == 0
    listed = capsys.readouterr().out.split()
    assert listed == SAMPLE_PAIRS  # the checkout carries every pair; a wheel three of them
    assert main(["process", "--sample", "pair_1000mm", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    truth = json.loads((REPO_ROOT / "sample_data" / "pair_1000mm" / "truth.json").read_text())
    assert (
        out["lock"]
        and np.linalg.norm(np.subtract(out["drogue"]["center_mm"], truth["center_mm"])) < 0.5
    )


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--sample", "pair_9999mm"], "no sample pair 'pair_9999mm'"),
        (["--sample", "pair_1000mm", "left.png", "right.png"], "not both"),
        ([], "give LEFT and RIGHT"),
        (["left.png"], "give LEFT and RIGHT"),
    ],
)
def test_sample_option_errors_are_one_line(argv, needle, capsys):
    assert main(["process", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err


def test_closed_pipe_is_not_a_traceback():
    """``aar-dock process --list-samples | head -0``: the reader is gone before we write."""
    import os
    import subprocess
    import sys

    exe = os.path.join(os.path.dirname(sys.executable), "aar-dock")
    proc = subprocess.Popen(
        [exe, "process", "--list-samples"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the child (≈ 1 s to start) writes anything
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
