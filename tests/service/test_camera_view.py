"""GET /api/v1/camera/{side}.jpg: the cameras' latest images with the detections drawn — the
LEDs of the telemetry record named by X-Seq, circled in their colours where the pipeline put
them; an uploaded pair the same way."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.server.main import create_app
from app.service.settings import Settings
from app.service.upload_pool import ExecutorFactory
from app.streams.annotations import led_color
from tests.support.upload_executor import thread_uploads

PAIR = Path(__file__).resolve().parents[2] / "sample_data" / "pair_1000mm_clutter"


def _led_colour_near(img_bgr: np.ndarray, u: float, v: float, rgb: tuple[int, int, int]) -> bool:
    """Some pixel within 12 px of (u, v) has the LED's colour (JPEG: within 60 per channel)."""
    h, w = img_bgr.shape[:2]
    y0, y1 = max(0, int(v) - 12), min(h, int(v) + 13)
    x0, x1 = max(0, int(u) - 12), min(w, int(u) + 13)
    patch = img_bgr[y0:y1, x0:x1, ::-1].reshape(-1, 3).astype(int)
    return bool((np.abs(patch - np.array(rgb)).max(axis=1) < 60).any())


def _check_drawn(jpeg: bytes, leds: list[dict], key: str, full_w: int) -> None:
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[1] == 480
    s = 480 / full_w
    for led in leds:
        u, v = led[key]
        assert _led_colour_near(img, u * s, v * s, led_color(led["id"])), led


def test_live_images_carry_the_records_detections(tmp_path: Path) -> None:
    settings = Settings(viser_enabled=False, recordings_dir=tmp_path, sim_auto_restart_s=None)  # type: ignore[call-arg]
    with TestClient(create_app(settings)) as c:
        seen: set[int] = set()
        locked_checked = 0
        deadline = time.monotonic() + 20
        while (len(seen) < 3 or locked_checked < 2) and time.monotonic() < deadline:
            left = c.get("/api/v1/camera/left.jpg")
            right = c.get("/api/v1/camera/right.jpg")
            if left.status_code == 404:
                time.sleep(0.1)
                continue
            assert left.status_code == right.status_code == 200
            assert left.headers["content-type"] == "image/jpeg"
            assert left.headers["cache-control"] == "no-store"
            seq = int(left.headers["x-seq"])
            seen.add(seq)
            hist = {r["seq"]: r for r in c.get("/api/v1/history", params={"seconds": 10}).json()}
            rec = hist.get(seq)
            if rec is not None and rec["lock"] and int(right.headers["x-seq"]) == seq:
                ids = [led["id"] for led in rec["pose"]["leds"]]
                assert left.headers["x-led-ids"] == ",".join(map(str, ids))
                assert left.headers["x-lock"] == "1"
                _check_drawn(left.content, rec["pose"]["leds"], "left_px", 1280)
                _check_drawn(right.content, rec["pose"]["leds"], "right_px", 1280)
                locked_checked += 1
            time.sleep(0.15)
        assert len(seen) >= 3, "the images did not follow the stream"
        assert locked_checked >= 2, "no locked frame checked"
        assert c.get("/api/v1/camera/top.jpg").status_code == 422
        assert c.get("/api/v1/camera/left.jpg", params={"source": "upload"}).status_code == 404


@pytest.mark.parametrize(
    "upload_executor", [None, thread_uploads], ids=["worker-process", "threads"]
)
def test_uploaded_pair_is_drawn_by_the_same_producer(
    tmp_path: Path, upload_executor: ExecutorFactory | None
) -> None:
    """The one upload path hands the camera view a complete raw side, whether its executor is
    the default worker processes or threads of the web process."""
    settings = Settings(  # type: ignore[call-arg]
        viser_enabled=False,
        recordings_dir=tmp_path,
        sim_autostart=False,
    )
    with TestClient(create_app(settings, upload_executor=upload_executor)) as c:
        assert c.get("/api/v1/camera/left.jpg").status_code == 404  # nothing yet, JSON reason
        files = {
            "left": ("left.png", (PAIR / "left.png").read_bytes(), "image/png"),
            "right": ("right.png", (PAIR / "right.png").read_bytes(), "image/png"),
        }
        res = c.post("/api/v1/stereo", files=files).json()
        assert res["lock"]
        for side in ("left", "right"):
            r = c.get(f"/api/v1/camera/{side}.jpg", params={"source": "upload"})
            assert r.status_code == 200
            assert r.headers["x-led-ids"] == ",".join(str(led["id"]) for led in res["leds"])
            rejected = res[f"rejected_{side}_px"]
            assert len(rejected) >= 5 and r.headers["x-rejected"] == str(len(rejected))
            img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
            for u, v in rejected:  # a grey tilted cross on each clutter light: its 4 arms
                x, y = round(u * 480 / 1280), round(v * 480 / 1280)
                arms = [img[y + dy, x + dx] for dx in (-3, 3) for dy in (-3, 3)]
                assert all(int(a.min()) > 80 for a in arms), (u, v, arms)
            _check_drawn(r.content, res["leds"], f"{side}_px", 1280)
        # the live stream is stopped: no live image
        assert c.get("/api/v1/camera/left.jpg").status_code == 404
