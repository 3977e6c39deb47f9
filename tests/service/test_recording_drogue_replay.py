"""The service's own recordings replay (issue 31 item 5, acceptance "Replay"): a recording
with frames made through the API on the default simulated stream (which flies a 24-inch
basket, not the paper's ring) carries its drogue profile and its calibration, in the frames
folder and in the MCAP log, and ``aar-dock track --left REC.frames`` / ``--left REC.mcap``,
with no other option, lock on ≥ 95 % of the pairs that were locked live."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.cli.main import main as cli_main
from app.streams.frame_log import read_index, recording_calibration, recording_drogue
from app.streams.mcap_source import mcap_calibration, mcap_drogue
from app.vision.drogue import BASKET_24IN
from tests.support.service_app import service_app
from tests.support.service_settings import service_settings
from tests.support.waiting import wait_until

RECORD_S = 4.0
MIN_REPLAYED = 0.95


def test_a_simulated_stream_recording_replays_with_its_own_drogue_and_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    settings = service_settings(tmp_path)
    with TestClient(service_app(settings)) as c:
        wait_until(lambda: c.get("/api/v1/healthz").json()["ticks"] >= 10, 60, "first ticks")
        assert c.get("/api/v1/healthz").json()["drogue"]["ring_radius_mm"] == 305.0
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 200, r.text
        time.sleep(RECORD_S)
        info = c.post("/api/v1/recording/stop").json()
    rec = tmp_path / "rec"
    frames, mcap = rec / info["frames_dir"], rec / info["mcap_file"]
    # the recording says which drogue and which calibration
    assert recording_drogue(frames) == mcap_drogue(mcap) == BASKET_24IN
    assert recording_calibration(frames) is not None and mcap_calibration(mcap) is not None
    live = {}
    for line in (rec / info["telemetry_file"]).read_text().splitlines():
        r = json.loads(line)
        live[r["seq"]] = bool(r["pose"]["lock"])
    entries = read_index(frames)
    locked_live = [live[e["record_seq"]] for e in entries]
    assert len(entries) >= 20 and sum(locked_live) >= 20, (len(entries), sum(locked_live))
    figures = {}
    for name, path in (("frames", frames), ("mcap", mcap)):
        out = tmp_path / f"{name}.jsonl"
        assert cli_main(["track", "--left", str(path), "--jsonl", str(out), "--no-progress"]) == 0
        rows = [json.loads(x) for x in out.open()]
        assert len(rows) == len(entries)
        both = sum(1 for row, was in zip(rows, locked_live, strict=True) if was and row["lock"])
        figures[name] = (both, sum(locked_live))
        assert both >= MIN_REPLAYED * sum(locked_live), figures
    print(f"replay: locked live {sum(locked_live)} of {len(entries)} pairs; replayed {figures}")
