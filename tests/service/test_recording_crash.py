"""Recordings survive a crash: metadata at start, flushed lines, recovery, a timer bound, kill -9."""

from __future__ import annotations

import gc
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.model.tick import TickRecord
from app.server.routers import recording as recording_router
from app.service.recording import SCENE_LOST_NOTE, Recorder
from tests.support.raw_frames import RawPair

ROOT = Path(__file__).resolve().parents[2]


def _record(i: int) -> TickRecord:
    return TickRecord(
        seq=i, source="sim", t_s=0.1 * i, clock_s=0.1 * i, wall_time=time.time(), phase="approach"
    )


class FakeSerializer:
    def __init__(self) -> None:
        self.t = 0.0

    def insert_sleep(self, duration: float) -> None:
        self.t += duration

    def serialize(self) -> bytes:
        return b"viser-scene" * 10


def _client(rec: Recorder) -> TestClient:
    """The real recording router over ``rec`` (no tick loop, no viser)."""
    app = FastAPI()
    app.include_router(recording_router.router, prefix="/api/v1")
    app.state.aar = SimpleNamespace(recorder=rec, settings=SimpleNamespace(token=None))
    return TestClient(app)


def _lines_on_disk(path: Path) -> int:
    """Complete (newline-terminated) lines, read through a handle of our own."""
    with path.open("rb") as f:
        return f.read().count(b"\n")


def _wait_gone(watchdog: list[threading.Thread]) -> None:
    """After the caller dropped its recorder (a crash: no stop()/close()), wait until the
    object is really gone (its file closed, its lock released): its watchdog thread exits
    once its weak reference is dead."""
    assert len(watchdog) == 1
    gc.collect()
    watchdog[0].join(timeout=3)
    assert not watchdog[0].is_alive(), "the watchdog kept the abandoned recorder alive"


def _meta(directory: Path, rec_id: str) -> dict:
    return json.loads((directory / f"{rec_id}.json").read_text())


def test_metadata_written_at_start_and_updated_at_stop(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=60, max_mb=5)
    info = rec.start()
    meta = _meta(tmp_path, info.id)
    assert meta["status"] == "recording" and meta["active"] is True
    assert meta["max_s"] == 60 and meta["max_mb"] == 5
    assert abs(meta["started_wall"] - time.time()) < 5
    assert not list(tmp_path.glob(".*"))  # no temp file left behind (atomic replace)
    rec.on_tick(_record(0))
    done = rec.stop()
    assert done is not None
    meta = _meta(tmp_path, info.id)
    assert meta["status"] == "complete" and meta["active"] is False
    assert meta["stop_reason"] == "stopped" and meta["ticks"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"{info.id}.json",
        f"{info.id}.jsonl",
        f"{info.id}.mcap",
    ]


def test_each_record_is_on_disk_before_stop(tmp_path: Path) -> None:
    rec = Recorder(tmp_path)
    info = rec.start()
    tele = tmp_path / info.telemetry_file
    for i in range(6):
        rec.on_tick(_record(i))
        assert _lines_on_disk(tele) == i + 1
        last = json.loads(tele.read_bytes().splitlines()[-1])
        assert last["seq"] == i
    rec.stop()


def test_abandoned_recording_is_recovered_as_interrupted(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=60, scene_serializer_factory=FakeSerializer)
    info = rec.start()
    assert info.scene_file == f"{info.id}.viser"
    records = [_record(i) for i in range(7)]
    for r in records:
        rec.on_tick(r)
        rec.on_scene_update(0.03)
    watchdog = [t for t in threading.enumerate() if t.name.endswith(info.id)]
    del rec  # a crash: no stop(), no close()
    _wait_gone(watchdog)

    fresh = Recorder(tmp_path)
    assert [r.id for r in fresh.recovered] == [info.id]
    got = fresh.get(info.id)
    assert got is not None
    assert got.status == "interrupted" and not got.active and got.ticks == 7
    assert got.last_record_wall == pytest.approx(records[-1].wall_time)
    assert got.stopped_wall == pytest.approx(records[-1].wall_time)
    assert got.started_wall == pytest.approx(info.started_wall)
    assert got.scene_file is None and got.scene_note == SCENE_LOST_NOTE
    assert got.max_s == 60

    with _client(fresh) as c:
        listed = c.get("/api/v1/recordings").json()
        assert [(x["id"], x["status"], x["ticks"]) for x in listed] == [(info.id, "interrupted", 7)]
        body = c.get(f"/api/v1/recordings/{info.id}").json()
        assert body["scene_note"] == SCENE_LOST_NOTE and body["scene_file"] is None
        tele = c.get(f"/api/v1/recordings/{info.id}/telemetry.jsonl")
        assert tele.status_code == 200
        assert [json.loads(x)["seq"] for x in tele.text.splitlines()] == list(range(7))
        scene = c.get(f"/api/v1/recordings/{info.id}/scene.viser")
        assert scene.status_code == 404 and SCENE_LOST_NOTE in scene.json()["detail"]
        # a new recording works next to the recovered one
        new_id = c.post("/api/v1/recording/start").json()["id"]
        assert c.get(f"/api/v1/recordings/{new_id}/telemetry.jsonl").status_code == 404
        assert c.post("/api/v1/recording/stop").json()["status"] == "complete"

    assert Recorder(tmp_path).recovered == []  # recovered once, then left alone


def test_orphan_jsonl_with_a_torn_last_line_is_recovered(tmp_path: Path) -> None:
    rec_id = "rec-20240101-000000-abcdef"
    good = [_record(i).model_dump_json() for i in range(3)]
    tele = tmp_path / f"{rec_id}.jsonl"
    tele.write_text("\n".join(good) + "\n" + good[0][:25])  # killed mid-write, no metadata
    (tmp_path / f".{rec_id}.viser.tmp").write_bytes(b"half a scene")
    rec = Recorder(tmp_path)
    got = rec.get(rec_id)
    assert got is not None and got.status == "interrupted" and got.ticks == 3
    assert got.started_wall == pytest.approx(json.loads(good[0])["wall_time"])
    assert got.recovery_note and "incomplete last record" in got.recovery_note
    assert "metadata was missing" in got.recovery_note
    assert tele.read_text() == "\n".join(good) + "\n"  # valid JSONL again
    assert got.telemetry_bytes == tele.stat().st_size
    assert not (tmp_path / f".{rec_id}.viser.tmp").exists()
    with _client(rec) as c:
        r = c.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl")
        assert r.status_code == 200 and len(r.text.splitlines()) == 3


def test_scene_written_before_the_crash_is_kept(tmp_path: Path) -> None:
    """Killed after the scene's atomic write but before the final metadata: keep the scene."""
    rec = Recorder(tmp_path, scene_serializer_factory=FakeSerializer)
    info = rec.start()
    rec.on_tick(_record(0))
    (tmp_path / f"{info.id}.viser").write_bytes(b"scene")
    watchdog = [t for t in threading.enumerate() if t.name.endswith(info.id)]
    del rec
    _wait_gone(watchdog)
    got = Recorder(tmp_path).get(info.id)
    assert got is not None and got.status == "interrupted"
    assert got.scene_file == f"{info.id}.viser" and got.scene_bytes == 5 and got.scene_note is None


def test_live_recording_is_not_recovered_by_another_recorder(tmp_path: Path) -> None:
    live = Recorder(tmp_path)
    info = live.start()
    live.on_tick(_record(0))
    other = Recorder(tmp_path)  # e.g. a second server on the same directory
    assert other.recovered == []
    assert _meta(tmp_path, info.id)["status"] == "recording"
    live.on_tick(_record(1))
    done = live.stop()
    assert done is not None and done.status == "complete" and done.ticks == 2
    assert _meta(tmp_path, info.id)["status"] == "complete"


def test_time_limit_without_ticks(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=1.0)
    t0 = time.monotonic()
    info = rec.start()
    while rec.active is not None and time.monotonic() - t0 < 5:
        time.sleep(0.02)
    elapsed = time.monotonic() - t0
    # the watchdog wakes at the bound; 1 s of slack for a loaded CI machine (2 shared cores)
    assert rec.active is None and 0.9 <= elapsed <= 2.0, elapsed
    # the recording leaves ``active`` before its metadata is rewritten (the stop finishes the
    # files outside the lock): wait for that write, bounded
    meta = _meta(tmp_path, info.id)
    while meta["status"] != "complete" and time.monotonic() - t0 < 5:
        time.sleep(0.02)
        meta = _meta(tmp_path, info.id)
    assert meta["status"] == "complete" and meta["stop_reason"] == "reached 1 s"
    assert meta["stopped_wall"] - meta["started_wall"] == pytest.approx(1.0, abs=0.5)


def test_time_limit_in_the_service_with_the_stream_stopped(tmp_path: Path) -> None:
    from app.server.main import create_app
    from app.service.settings import Settings

    settings = Settings(
        recordings_dir=tmp_path,
        recording_max_s=1.0,
        sim_autostart=False,  # no stream: no tick ever reaches the recorder
        viser_enabled=False,
    )
    with TestClient(create_app(settings)) as c:
        t0 = time.monotonic()
        rec_id = c.post("/api/v1/recording/start").json()["id"]
        while c.get(f"/api/v1/recordings/{rec_id}").json()["active"]:
            assert time.monotonic() - t0 < 3, "the time bound was not enforced"
            time.sleep(0.05)
        elapsed = time.monotonic() - t0  # the bound, not the service's shutdown
        info = c.get(f"/api/v1/recordings/{rec_id}").json()
    assert elapsed <= 1.6
    assert info["status"] == "complete" and info["stop_reason"] == "reached 1 s"
    assert info["ticks"] == 0


def test_late_tick_is_not_written_past_the_time_limit(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=0.3)
    info = rec.start()
    rec.on_tick(_record(0))
    time.sleep(0.8)
    rec.on_tick(_record(1))  # after the bound: dropped
    got = rec.get(info.id)
    assert got is not None and got.ticks == 1 and got.stop_reason == "reached 0.3 s"
    assert _lines_on_disk(tmp_path / info.telemetry_file) == 1


def test_close_stops_the_watchdog(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=100)
    info = rec.start()
    watchdog = [t for t in threading.enumerate() if t.name.endswith(info.id)]
    assert len(watchdog) == 1 and watchdog[0].is_alive()
    rec.close()
    watchdog[0].join(timeout=2)
    assert not watchdog[0].is_alive()
    assert _meta(tmp_path, info.id)["stop_reason"] == "server shutdown"


# ---- a real kill -9 of the service ---------------------------------------------------------
def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _serve(rec_dir: Path, log_path: Path) -> tuple[subprocess.Popen[bytes], str]:
    port, viser_port = _free_port(), _free_port()
    exe = shutil.which("aar-dock", path=str(Path(sys.executable).parent)) or "aar-dock"
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env["AAR_LOG_LEVEL"] = "warning"
    cmd = [exe, "serve", "--port", str(port), "--viser-port", str(viser_port)]
    cmd += ["--recordings-dir", str(rec_dir)]
    with log_path.open("ab") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}/api/v1"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"server exited: {log_path.read_text()[-2000:]}")
        try:
            if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"server did not come up: {log_path.read_text()[-2000:]}")


def _end(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_recording_survives_kill_9_of_the_server(tmp_path: Path) -> None:
    rec_dir, log = tmp_path / "rec", tmp_path / "serve.log"
    proc, base = _serve(rec_dir, log)
    try:
        start = httpx.post(f"{base}/recording/start", timeout=5).json()
        rec_id = start["id"]
        assert _meta(rec_dir, rec_id)["status"] == "recording"
        time.sleep(2.0)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        _end(proc)
    on_disk = _lines_on_disk(rec_dir / f"{rec_id}.jsonl")
    assert on_disk >= 20  # ~30 Hz for 2 s
    assert _meta(rec_dir, rec_id)["status"] == "recording"  # no clean stop happened

    proc, base = _serve(rec_dir, log)
    try:
        info = httpx.get(f"{base}/recordings/{rec_id}", timeout=5).json()
        assert info["status"] == "interrupted" and info["active"] is False
        assert on_disk - 1 <= info["ticks"] <= on_disk
        assert info["scene_file"] is None and info["scene_note"] == SCENE_LOST_NOTE
        listed = httpx.get(f"{base}/recordings", timeout=5).json()
        assert any(x["id"] == rec_id and x["status"] == "interrupted" for x in listed)
        tele = httpx.get(f"{base}/recordings/{rec_id}/telemetry.jsonl", timeout=5)
        assert tele.status_code == 200
        lines = [json.loads(x) for x in tele.text.splitlines()]
        assert len(lines) == info["ticks"]
        assert info["last_record_wall"] == pytest.approx(lines[-1]["wall_time"])
        scene = httpx.get(f"{base}/recordings/{rec_id}/scene.viser", timeout=5)
        assert scene.status_code == 404 and SCENE_LOST_NOTE in scene.json()["detail"]
    finally:
        _end(proc)


def test_frames_of_an_abandoned_recording_are_recovered_and_replayable(tmp_path: Path) -> None:
    """A crash during a recording with raw frames: every pair whose index line was written
    is recovered (``frame_pairs``) and reads back losslessly."""
    import numpy as np

    from app.geometry.calibration import paper_calibration
    from app.streams.frame_log import FrameRecordingSource, recording_calibration

    calib = paper_calibration()
    rec = Recorder(tmp_path, max_s=60)
    info = rec.start(frames=True, calibration=calib)
    assert info.frames_dir == f"{info.id}.frames"
    images = []
    for i in range(6):
        left = np.full((16, 20), i, np.uint8)
        right = np.full((16, 20), 100 + i, np.uint8)
        images.append((left, right))
        rec.on_tick(_record(i), RawPair(left_image=left, right_image=right))
    writer = rec.frame_writer
    deadline = time.monotonic() + 10
    while writer.pairs < 6 and time.monotonic() < deadline:  # the writer thread catches up
        time.sleep(0.01)
    frames_dir = tmp_path / info.frames_dir
    with open(frames_dir / "frames.jsonl", "ab") as f:  # killed while writing pair 7
        f.write(b'{"i": 6, "se')
    watchdog = [t for t in threading.enumerate() if t.name.endswith(info.id)]
    del rec, writer  # a crash: no stop()
    _wait_gone(watchdog)

    got = Recorder(tmp_path).get(info.id)
    assert got is not None and got.status == "interrupted"
    assert got.frames_dir == info.frames_dir and got.frame_pairs == 6 and got.ticks == 6
    src = FrameRecordingSource(frames_dir)
    for i, (left, right) in enumerate(images):
        frame = src.read()
        assert frame is not None and frame.seq == i and frame.t_s == pytest.approx(0.1 * i)
        assert np.array_equal(frame.left, left) and np.array_equal(frame.right, right)
    assert np.array_equal(recording_calibration(frames_dir).R, calib.R)
