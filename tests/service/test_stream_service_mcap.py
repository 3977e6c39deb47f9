"""Issue 33, cases 4 and 5 on a live service: an MCAP source whose message turns corrupt after
good pairs is ``failed`` and ``/healthz`` is ``degraded`` with the reason (it was ``ended`` and
``ok``: corruption looked like a normal end); a degenerate calibration inside an MCAP is
refused with the same message as ``PUT /calibration``."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from app.resources import load_default_calibration
from tests.support.hostile_mcap import LEFT, RIGHT, LogWriter, compressed_image, png, valid_log
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.waiting import wait_until


def _late_corruption(p: Path) -> Path:
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        for i in range(3):
            log.pair(1_000_000_000 + i * 33_000_000, i, png(seed=i), png(seed=10 + i))
        log.add(LEFT, 2_000_000_000, b"\xff" * 40)  # not a protobuf CompressedImage
        log.add(RIGHT, 2_000_000_000, compressed_image(png()))
        log.finish()
    return p


def test_corruption_after_good_pairs_turns_healthz_degraded_not_ended(tmp_path: Path) -> None:
    bad = _late_corruption(tmp_path / "late.mcap")
    settings = service_settings(tmp_path, **SIM_IDLE, source=f"mcap:{bad}", stream_realtime=False)
    with TestClient(service_app(settings)) as c:
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] != "running", 20.0)
        status = c.get("/api/v1/stream").json()
        assert status["state"] == "failed" and status["frames"] == 3, status
        health = c.get("/api/v1/healthz").json()
        assert health["status"] == "degraded", health
        stream = [h for h in health["components"] if h["name"].startswith("stream:")]
        assert stream and stream[0]["status"] == "degraded"
        assert "corrupt foxglove.CompressedImage" in stream[0]["reason"]
        assert "at log time 2000000000" in stream[0]["reason"]


def test_a_degenerate_mcap_calibration_is_refused_as_put_calibration_refuses_it(
    tmp_path: Path,
) -> None:
    data = load_default_calibration().to_dict()
    data["left"]["K"][0][0] = 1e-300
    w, h = data["image_size"]
    rec = tmp_path / "rec"
    rec.mkdir()
    p = valid_log(rec / "calib.mcap", 1, calibration=data, shape=(h, w))
    with TestClient(service_app(service_settings(tmp_path, **SIM_IDLE))) as c:
        put = c.put("/api/v1/calibration", json=data)
        assert put.status_code == 422
        detail = put.json()["detail"]
        assert "fx = 1e-300" in detail
        r = c.put("/api/v1/stream/source", json={"source": f"mcap:{p}"})
        assert r.status_code == 422, r.text
        assert detail in r.json()["detail"]
