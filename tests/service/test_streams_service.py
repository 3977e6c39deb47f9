"""Frame sources in the service: ``serve --source video:``, the push WebSocket with
``aar-dock push`` (real CLI processes), source switching, and raw-frame recordings that replay
to the live results (``aar-dock track`` and ``serve --source video:<recording>``)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.cli.main import main as cli_main
from app.service.settings import Settings
from app.streams.protocol import encode_message
from tests.support.inline_sim import inline_sim
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.stream_checks import assert_same_pose, history_records
from tests.support.streams_sequence import cached_sequence, read_jsonl, write_avi, write_png_folders
from tests.support.waiting import stop_process, wait_for_server, wait_until

N = 40
ROOT = Path(__file__).resolve().parents[2]


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(tmp_path, **{**SIM_IDLE, "history_s": 600.0, **kw})


@pytest.fixture(scope="module")
def media(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("media")
    seq = cached_sequence(N)
    la, ra = write_avi(seq, d)
    lp, rp = write_png_folders(seq, d)
    return {"left_avi": la, "right_avi": ra, "left_png": lp, "right_png": rp}


def test_serve_video_source_publishes_locked_video_records_with_guidance(
    tmp_path: Path, media: dict[str, Path]
) -> None:
    source = f"video:{media['left_avi']},{media['right_avi']}"
    app = service_app(_settings(tmp_path, source=source, stream_realtime=False))
    with TestClient(app) as c:
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of video")
        status = c.get("/api/v1/stream").json()
        recs = history_records(c, "video")
    assert status["kind"] == "video" and status["pairs"] == N and status["dropped_skew"] == 0
    assert [r["stream"]["frame"] for r in recs] == list(range(N))
    assert sum(r["lock"] for r in recs) >= 0.95 * N
    assert all(r["uav_state"] is None and r["control"] is None for r in recs)  # no controller
    last = recs[-1]
    g = last["guidance"]
    # the sequence closes at 15 mm per frame at 30 fps: 0.45 m/s
    assert g["closure_speed_mps"] == pytest.approx(0.45, abs=0.03)
    gap = last["rel_position_m"][0]
    assert g["time_to_contact_s"] == pytest.approx(gap / g["closure_speed_mps"], rel=1e-6)
    centre = cached_sequence(N).centers_mm[N - 1] / 1e3
    assert last["drogue_measured_m"] == pytest.approx([centre[2], centre[0], centre[1]], abs=2e-3)


def test_frame_recording_replays_to_the_live_results(
    tmp_path: Path, media: dict[str, Path]
) -> None:
    source = f"video:{media['left_png']},{media['right_png']}"
    app = service_app(_settings(tmp_path, source=source, stream_fps=15.0))  # paced, 15 fps
    with TestClient(app) as c:
        wait_until(lambda: c.get("/api/v1/stream").json()["frames"] >= 5, 30, "first frames")
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 200, r.text
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of video")
        info = c.post("/api/v1/recording/stop").json()
        live = {r["stream"]["frame"]: r for r in history_records(c, "video")}
        frames_dir = tmp_path / "rec" / info["frames_dir"]
        assert info["frames_dropped"] == 0, "the frame writer fell behind: test not valid"
        assert 20 <= info["frame_pairs"] < N
        # replay 1: serve --source video:<recording> (switched through the API)
        r = c.put(
            "/api/v1/stream/source", json={"source": f"video:{frames_dir}", "realtime": False}
        )
        assert r.status_code == 200, r.text
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of replay")
        served = [r for r in c.get("/api/v1/history?seconds=600").json() if r["source"] == "video"]
        served = served[len(live) :]
    # replay 2: aar-dock track on the recording (calibration from the recording)
    out = tmp_path / "replay.jsonl"
    assert cli_main(["track", "--left", str(frames_dir), "--jsonl", str(out), "--no-progress"]) == 0
    rows = read_jsonl(out)
    assert len(rows) == len(served) == info["frame_pairs"]
    assert rows[0]["mode"] == "acquired"  # the recording starts with a fresh acquisition
    for row, srv in zip(rows, served, strict=True):
        ref = live[row["frame"]]
        assert srv["stream"]["frame"] == row["frame"]
        for other in (row, srv["pose"]):
            assert_same_pose(ref["pose"], other)
        assert row["mode"] == ref["stream"]["mode"] == srv["stream"]["mode"]


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()


def test_push_websocket_token_limits_and_locked_push_records(tmp_path: Path) -> None:
    seq = cached_sequence(N)
    app = service_app(_settings(tmp_path, token="s3cret", push_max_mb=3.0))
    with TestClient(app) as c:
        # switching needs the token; push needs the token
        assert c.put("/api/v1/stream/source", json={"source": "push"}).status_code == 401
        with pytest.raises(WebSocketDisconnect) as exc:
            with c.websocket_connect("/api/v1/stream/push") as ws:
                ws.receive_text()
        assert exc.value.code == 1008
        auth = {"Authorization": "Bearer s3cret"}
        with c.websocket_connect("/api/v1/stream/push", headers=auth) as ws:
            ws.send_bytes(encode_message(_png(seq.lefts[0]), _png(seq.rights[0]), t_s=0, seq=0))
            assert "not push" in json.loads(ws.receive_text())["error"]  # the source is sim
        r = c.put("/api/v1/stream/source", json={"source": "push"}, headers=auth)
        assert r.status_code == 200 and r.json()["state"] == "running"
        with c.websocket_connect("/api/v1/stream/push?token=s3cret") as ws:
            ws.send_bytes(b"garbage")
            assert "prefix" in json.loads(ws.receive_text())["error"]
            for i in range(12):
                msg = encode_message(
                    _png(seq.lefts[i]), _png(seq.rights[i]), t_s=i / 30, seq=i, exposure_ms=1.5
                )
                ws.send_bytes(msg)
                wait_until(
                    lambda i=i: c.get("/api/v1/stream").json()["frames"] > i, 20, f"pair {i}"
                )
            ws.send_text("stats")
            stats = json.loads(ws.receive_text())
            assert stats["received"] == 12 and stats["rejected"] >= 1
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.send_bytes(b"\0" * 3_100_000)
                ws.receive_text()
            assert exc.value.code == 1009
        recs = history_records(c, "push")
    assert [r["stream"]["frame"] for r in recs] == list(range(12))
    assert all(r["lock"] for r in recs)
    assert recs[-1]["guidance"]["closure_speed_mps"] == pytest.approx(0.45, abs=0.05)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def served_push(tmp_path: Path) -> Iterator[tuple[str, int]]:
    """``aar-dock serve --source push`` as a real process (token s3cret)."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_TOKEN="s3cret")
    env.update(AAR_LOG_LEVEL="warning", AAR_RECORDINGS_DIR=str(tmp_path / "rec"))
    cmd = [sys.executable, "-m", "app", "serve", "--source", "push", "--no-viser", "--no-sim"]
    log = (tmp_path / "serve.log").open("wb")
    proc = subprocess.Popen(cmd + ["--port", str(port)], cwd=ROOT, env=env, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}/api/v1"
    try:
        wait_for_server(
            proc,
            lambda: httpx.get(f"{base}/healthz", timeout=1).status_code == 200,
            tmp_path / "serve.log",
        )
        yield base, port
    finally:
        stop_process(proc)
        log.close()


@pytest.mark.parametrize("fmt", ["png", "bmp"])
def test_push_cli_to_serve_cli(
    served_push: tuple[str, int], media: dict[str, Path], fmt: str
) -> None:
    base, port = served_push
    url = f"ws://127.0.0.1:{port}/api/v1/stream/push"
    cmd = [sys.executable, "-m", "app", "push", "--left", str(media["left_avi"])]
    cmd += ["--right", str(media["right_avi"]), "--url", url, "--fps", "15", "--count", "20"]
    cmd += ["--format", fmt]
    bad = subprocess.run(cmd + ["--token", "wrong"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and "403" in bad.stderr
    proc = subprocess.run(cmd + ["--token", "s3cret"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "pushed 20 pairs" in proc.stdout
    wait_until(
        lambda: (
            httpx.get(f"{base}/stream").json()["frames"]
            + httpx.get(f"{base}/stream").json()["dropped_backpressure"]
            >= 20
        ),
        30,
        "pushed pairs processed",
    )
    status = httpx.get(f"{base}/stream").json()
    assert status["received"] == 20 and status["rejected"] == 0
    assert status["frames"] + status["dropped_backpressure"] == 20
    recs = [r for r in httpx.get(f"{base}/history?seconds=60").json() if r["source"] == "push"]
    assert len(recs) == status["frames"] >= 10
    assert sum(r["lock"] for r in recs) >= 0.95 * len(recs)
    assert recs[-1]["stream"]["frame"] == 19  # the newest pair is never the one dropped


class _FakeSim:
    """A stand-in simulation (what the worker steps): one tick a step, never done."""

    done = False

    def __init__(self) -> None:
        self.t = 0.0

    def step(self) -> Any:
        from tests.support.fake_sim import FakeSimState

        self.t += 1 / 30
        return FakeSimState(t_s=self.t, pose=None, lock=False, lock_reason="fake sim")


def test_one_source_at_a_time_sim_start_stops_the_stream(
    tmp_path: Path, media: dict[str, Path]
) -> None:
    source = f"video:{media['left_avi']},{media['right_avi']}"
    settings = _settings(tmp_path, source=source, stream_loop=True)  # real time, endless
    app = service_app(settings, source_factory=inline_sim(lambda config, calib: _FakeSim()))
    with TestClient(app) as c:
        st = c.app.state.aar  # type: ignore[attr-defined]
        assert not st.loop.running  # the stream replaced the simulation
        wait_until(lambda: c.get("/api/v1/stream").json()["frames"] >= 3, 30, "video frames")
        assert c.post("/api/v1/sim/start").status_code == 200
        status = c.get("/api/v1/stream").json()
        assert (status["source"], status["state"]) == ("sim", "sim")
        n_video = len(history_records(c, "video"))
        wait_until(lambda: len(history_records(c, "sim")) >= 5, 30, "simulated ticks")
        assert len(history_records(c, "video")) == n_video  # the stream thread is gone
        r = c.put("/api/v1/stream/source", json={"source": "camera:/no/such/device.avi"})
        assert r.status_code == 422 and "device index or a /dev/video" in r.json()["detail"]
        assert st.loop.running  # a refused source changes nothing


def test_a_frame_recording_replays_with_its_own_calibration(tmp_path: Path) -> None:
    from app.geometry.calibration import StereoCalibration, paper_calibration
    from app.model.frames import StereoFrame
    from app.resources import load_default_calibration
    from app.service.stream_service import StreamService
    from app.service.tick_loop import TickLoop
    from app.sim.sim_config import SimConfig
    from app.streams.frame_log import FrameRecordingWriter

    data = paper_calibration().to_dict()
    data["T"] = [-120.0, 0.5, -28.3]  # another rig than the service's
    recorded_with = StereoCalibration.from_dict(data)
    writer = FrameRecordingWriter(tmp_path / "r.frames", recorded_with)
    img = np.zeros((8, 8), np.uint8)
    writer.submit(StereoFrame(img, img, t_s=0.0, seq=0))
    writer.close()
    service_calib = load_default_calibration()
    loop = TickLoop(SimConfig(), service_calib, source_factory=inline_sim(lambda c, k: _FakeSim()))
    streams = StreamService(loop, service_calib, _settings(tmp_path))
    try:
        streams.switch(f"video:{tmp_path / 'r.frames'}", realtime=False)
        assert streams.processor is not None
        used = streams.processor.calibration
        assert np.array_equal(used.R, recorded_with.R) and np.array_equal(used.T, recorded_with.T)
        assert not np.array_equal(service_calib.T, recorded_with.T)
    finally:
        streams.close()


def test_every_source_prefix_with_a_path_outside_the_roots_is_refused(tmp_path: Path) -> None:
    """Issue 33 (source specs): camera:, video: and mcap: naming files outside
    AAR_STREAM_ROOTS get 422 and no file's pixels are served."""
    allowed = tmp_path / "allowed"
    allowed.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    img = np.full((48, 64), 200, np.uint8)
    for name in ("l.png", "r.png"):
        cv2.imwrite(str(outside / name), img)
    (outside / "f.mcap").write_bytes(b"\x89MCAP0\r\n")
    settings = _settings(tmp_path, stream_roots=[allowed])
    app = service_app(settings, source_factory=inline_sim(lambda config, calib: _FakeSim()))
    with TestClient(app) as c:
        for spec in (
            f"camera:{outside / 'l.png'}",
            f"camera:{outside / 'l.png'},{outside / 'r.png'}",
            f"video:{outside / 'l.png'},{outside / 'r.png'}",
            f"video:{outside}",
            f"mcap:{outside / 'f.mcap'}",
            f"video:{allowed}/../outside/l.png,{allowed}/../outside/r.png",
        ):
            r = c.put("/api/v1/stream/source", json={"source": spec})
            assert r.status_code == 422, (spec, r.text)
            assert c.get("/api/v1/stream").json()["source"] == "sim", spec
        # nothing from the outside folder was opened: the stream never left the simulation
        assert not history_records(c, "camera") and not history_records(c, "video")
