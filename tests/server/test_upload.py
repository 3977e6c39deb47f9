"""Uploads of the sample stereo pairs through ``POST /stereo`` against their ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.server.main import create_app
from app.service.settings import Settings
from tests.support.inline_sim import inline_sim

REPO = Path(__file__).resolve().parents[2]
PAIRS = sorted(p for p in (REPO / "sample_data").glob("pair_*") if p.is_dir())


class _IdleSource:
    done = False

    def step(self):  # pragma: no cover - never stepped: the stream is stopped
        raise AssertionError("not used")


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("upload")
    settings = Settings(viser_enabled=False, sim_autostart=False, recordings_dir=tmp / "rec")  # type: ignore[call-arg]
    app = create_app(settings, source_factory=inline_sim(lambda cfg, cal: _IdleSource()))
    with TestClient(app) as c:
        yield c


def test_sample_pairs_exist() -> None:
    assert len(PAIRS) >= 3, "sample_data/pair_* missing"


@pytest.mark.parametrize("pair", PAIRS, ids=[p.name for p in PAIRS])
def test_upload_sample_pair_matches_truth(client: TestClient, pair: Path) -> None:
    truth = json.loads((pair / "truth.json").read_text())
    files = {
        "left": ("left.png", (pair / "left.png").read_bytes(), "image/png"),
        "right": ("right.png", (pair / "right.png").read_bytes(), "image/png"),
    }
    r = client.post("/api/v1/stereo", files=files)
    assert r.status_code == 200, r.text
    res = r.json()
    visible = [i for i, v in zip(truth["led_ids"], truth["visible"], strict=True) if v]
    assert res["lock"] is True, res["reason"]
    assert sorted(led["id"] for led in res["leds"]) == sorted(visible)
    truth_xyz = {i: np.array(x) for i, x in zip(truth["led_ids"], truth["led_xyz_mm"], strict=True)}
    errs = [np.linalg.norm(np.array(led["xyz_mm"]) - truth_xyz[led["id"]]) for led in res["leds"]]
    assert max(errs) < 1.0, errs
    centre_err = np.linalg.norm(np.array(res["drogue"]["center_mm"]) - np.array(truth["center_mm"]))
    assert centre_err < 1.0
    # the upload is published to the dashboard stream as well
    state = client.get("/api/v1/state").json()
    assert state["source"] == "upload" and len(state["pose"]["leds"]) == len(res["leds"])


def test_upload_jpeg_and_bmp_are_accepted(client: TestClient) -> None:
    import cv2

    pair = REPO / "sample_data" / "pair_1000mm"
    left = cv2.imread(str(pair / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(pair / "right.png"), cv2.IMREAD_UNCHANGED)
    for ext in (".bmp", ".tiff", ".jpg"):
        files = {
            "left": (f"l{ext}", cv2.imencode(ext, left)[1].tobytes()),
            "right": (f"r{ext}", cv2.imencode(ext, right)[1].tobytes()),
        }
        r = client.post("/api/v1/stereo", files=files)
        assert r.status_code == 200, (ext, r.text)
        assert len(r.json()["leds"]) == 5, ext
