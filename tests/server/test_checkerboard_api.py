"""``POST /api/v1/calibration/checkerboard`` on a tiny FastAPI app that includes the router."""

from __future__ import annotations

import base64
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.geometry.calibration import StereoCalibration
from app.server.routers.checkerboard import router
from app.sim.checkerboard_render import load_truth

REPO = Path(__file__).resolve().parents[2]
SET_DIR = REPO / "sample_data" / "checkerboard"
URL = "/api/v1/calibration/checkerboard"


@pytest.fixture(scope="module")
def client():
    app = FastAPI()
    app.include_router(router, prefix="/api/v1")
    with TestClient(app) as c:
        yield c


def _files(indices, right_override: dict[int, bytes] | None = None):
    files = []
    for k in indices:
        files.append(
            (
                "left",
                (f"left_{k:02d}.png", (SET_DIR / f"left_{k:02d}.png").read_bytes(), "image/png"),
            )
        )
    for k in indices:
        data = (right_override or {}).get(k) or (SET_DIR / f"right_{k:02d}.png").read_bytes()
        files.append(("right", (f"right_{k:02d}.png", data, "image/png")))
    return files


def test_good_set_returns_calibration_and_report(client):
    idx = [0, 2, 4, 6, 8, 10, 12]
    form = {"board": "9x6", "square_mm": "25", "include_png": "true", "estimate_skew": "true"}
    r = client.post(URL, files=_files(idx), data=form)
    assert r.status_code == 200, r.text
    body = r.json()
    calib = StereoCalibration.from_dict(body["calibration"])  # validates
    truth, _, _ = load_truth(SET_DIR / "truth.json")
    assert calib.baseline_mm == pytest.approx(truth.baseline_mm, abs=0.5)
    assert calib.left.fx == pytest.approx(truth.left.fx, rel=3e-3)
    rep = body["report"]
    assert rep["views_used"] == 7 and rep["rejected"] == []
    assert [v["name"] for v in rep["views"]] == [f"{k:02d}" for k in idx]
    assert rep["stereo_rms_px"] < 0.3
    assert rep["baseline_mm"] == pytest.approx(calib.baseline_mm)
    # the sample set is rendered with γ = 0: the estimated skew is near 0 (and reported)
    assert abs(calib.left.skew) < 1.0 and rep["intrinsics"]["left"]["skew"] == calib.left.skew
    # the sample set is rendered with γ = 0: the estimated skew is near 0 (and reported)
    assert abs(calib.left.skew) < 1.0 and rep["intrinsics"]["left"]["skew"] == calib.left.skew
    png = base64.b64decode(body["report_png_base64"])
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[0] > 400


def test_undecodable_image_is_400(client):
    files = _files([0, 1], right_override={1: b"\x89PNG but not really"})
    r = client.post(URL, files=files, data={"board": "9x6", "square_mm": "25"})
    assert r.status_code == 400
    assert (
        r.json()["detail"]
        == "right image #1 (right_01.png) is not a decodable image (PNG, JPEG, ...)"
    )


def test_image_whose_header_lies_about_its_size_is_422_before_decoding(client, monkeypatch):

    from app.server.routers import checkerboard
    from tests.support.hostile_images import hostile_tiff

    def no_decode(*a, **k):
        raise AssertionError("decoder reached")

    monkeypatch.setattr(checkerboard, "_decode", no_decode)
    files = _files([0, 1], right_override={1: hostile_tiff()})
    r = client.post(URL, files=files, data={"board": "9x6", "square_mm": "25"})
    assert r.status_code == 422, r.text
    assert "ImageWidth written twice" in r.json()["detail"]


def test_three_views_is_422(client):
    r = client.post(URL, files=_files([0, 1, 2]), data={"board": "9x6", "square_mm": "25"})
    assert r.status_code == 422
    assert r.json()["detail"].startswith(
        "too few usable views: only 3 pairs given, need at least 6"
    )


def test_count_mismatch_and_sizes_differ_are_422(client):
    files = _files([0, 1])[:-1]  # two left, one right
    r = client.post(URL, files=files, data={"board": "9x6"})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("2 left images but 1 right images")
    small = cv2.imencode(".png", np.full((512, 640), 90, np.uint8))[1].tobytes()
    r = client.post(URL, files=_files([0, 1], right_override={0: small}), data={"board": "9x6"})
    assert r.status_code == 422
    assert r.json()["detail"].startswith("image sizes differ: right image of pair 00 is 640x512 px")


def test_bad_form_values_are_422(client):
    r = client.post(URL, files=_files([0]), data={"board": "nine-by-six"})
    assert r.status_code == 422 and "expected COLSxROWS" in r.json()["detail"]
    r = client.post(URL, files=_files([0]), data={"board": "9x6", "square_mm": "-1"})
    assert r.status_code == 422  # FastAPI validation (gt=0)
    r = client.post(URL, files=_files([0]), data={"board": "9x6", "model": "fisheye"})
    assert r.status_code == 422
    r = client.post(URL, data={"board": "9x6"})  # no files at all
    assert r.status_code == 422


BOUGUET = REPO / "tests" / "data" / "real" / "bouguet_stereo"


def test_real_photographs_report_fields_and_mismatched_pair(client):
    """Bouguet's real pairs (JPEG); pair 06's right image is replaced by pair 07's (not taken
    at the same instant): the rig check rejects it with the reason; the extended report
    (dropped, coverage, held_out, detectors) is in the response."""
    lefts = sorted(BOUGUET.glob("left*.jpg"))
    rights = sorted(BOUGUET.glob("right*.jpg"))
    rights[5] = rights[6]
    files = [("left", (p.name, p.read_bytes(), "image/jpeg")) for p in lefts]
    files += [
        ("right", (f"right{lp.name[4:]}", rp.read_bytes(), "image/jpeg"))
        for lp, rp in zip(lefts, rights, strict=True)
    ]
    r = client.post(URL, files=files, data={"board": "9x6", "square_mm": "30"})
    assert r.status_code == 200, r.text
    rep = r.json()["report"]
    assert [x["name"] for x in rep["rejected"]] == ["06"]
    assert rep["rejected"][0]["reason"].startswith("left/right grids inconsistent with the rig")
    assert rep["views_used"] == 12 and rep["dropped"] == []
    assert rep["detectors"] == {"classic": 26}
    assert rep["held_out"]["rms_mm"] < 0.5
    assert sum(map(sum, rep["coverage"]["left"])) == 12 * 54
    left = rep["intrinsics"]["left"]
    assert left["fx"] == pytest.approx(533.5, rel=1.5e-3)
    assert rep["baseline_mm"] == pytest.approx(99.81, rel=1.5e-3)
