"""Recording with the real viser scene: JSONL + .viser file, bounded size, replay assets."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.server.main import create_app
from app.server.settings import Settings

sys.path.insert(0, str(Path(__file__).parent))
from test_server_api import FakeSim  # noqa: E402  (the tests' fake step source)


def _app(tmp_path: Path, **kw: object):
    settings = Settings(
        viser_port=0, recordings_dir=tmp_path / "rec", sim_auto_restart_s=None, **kw
    )  # type: ignore[arg-type]
    return create_app(settings, source_factory=lambda cfg, cal: FakeSim(cfg, cal))


def _wait_stopped(c: TestClient, rec_id: str, timeout: float = 20.0) -> dict:
    deadline = time.time() + timeout
    while time.time() < deadline:
        info = c.get(f"/api/v1/recordings/{rec_id}").json()
        if not info["active"]:
            return info
        time.sleep(0.1)
    raise AssertionError("recording did not stop")


def test_recording_writes_jsonl_and_viser_scene(tmp_path: Path) -> None:
    with TestClient(_app(tmp_path)) as c:
        cfg = c.get("/api/v1/config").json()
        assert cfg["viser_port"] and cfg["viser_url"].endswith(f":{cfg['viser_port']}/")
        rec_id = c.post("/api/v1/recording/start").json()["id"]
        time.sleep(1.5)
        info = c.post("/api/v1/recording/stop").json()
        assert info["ticks"] >= 10 and info["scene_file"] == f"{rec_id}.viser"
        scene = c.get(f"/api/v1/recordings/{rec_id}/scene.viser")
        assert scene.status_code == 200 and len(scene.content) == info["scene_bytes"] > 1000
        tele = c.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl").text.splitlines()
        recs = [json.loads(x) for x in tele]
        assert len(recs) == info["ticks"]
        assert all(r["source"] == "sim" for r in recs)
        # the viser client for offline replay is served locally
        client_page = c.get("/viser-client/")
        assert client_page.status_code == 200 and "<html" in client_page.text.lower()
    files = sorted(p.name for p in (tmp_path / "rec").iterdir())
    assert files == sorted([f"{rec_id}.json", f"{rec_id}.jsonl", f"{rec_id}.viser"])


def test_recording_is_bounded(tmp_path: Path) -> None:
    with TestClient(_app(tmp_path, recording_max_mb=0.02)) as c:
        rec_id = c.post("/api/v1/recording/start").json()["id"]
        info = _wait_stopped(c, rec_id)
        assert "MB" in info["stop_reason"]
        assert info["telemetry_bytes"] <= 0.02e6 + 5000  # at most one record past the bound
    with TestClient(_app(tmp_path / "b", recording_max_s=0.5)) as c:
        rec_id = c.post("/api/v1/recording/start").json()["id"]
        info = _wait_stopped(c, rec_id)
        assert "s" in info["stop_reason"] and info["stopped_wall"] - info["started_wall"] < 5
