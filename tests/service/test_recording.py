"""Recording with the real viser scene: JSONL + .viser file, bounded size, replay assets."""

from __future__ import annotations

import builtins
import errno
import io
import json
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.model.tick import TickRecord
from app.server.main import create_app
from app.server.routers import recording as recording_router
from app.service.recording import Recorder
from app.service.settings import Settings
from tests.support.fake_sim import FakeSim  # the tests' fake step source
from tests.support.inline_sim import inline_sim
from tests.support.raw_frames import RawPair


def _app(tmp_path: Path, **kw: object):
    settings = Settings(
        viser_port=0, recordings_dir=tmp_path / "rec", sim_auto_restart_s=None, **kw
    )  # type: ignore[arg-type]
    return create_app(settings, source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)))


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
    assert files == sorted(
        [f"{rec_id}.json", f"{rec_id}.jsonl", f"{rec_id}.mcap", f"{rec_id}.viser"]
    )


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


# ---- a failing disk ---------------------------------------------------------------------------
# A 15 MB file system that fills: a real tmpfs where one can be mounted (root), and always a
# fault-injecting one (every file opened for writing under the directory shares a 15 MB quota,
# the write that crosses it writes what fits and raises ENOSPC, like a full disk; the free space
# it reports is the quota less what the files hold, so deleting files gives the space back).
DISK_MB = 15


class QuotaFile:
    """A file object whose writes count against the :class:`InjectedDisk`'s quota."""

    def __init__(self, real: Any, disk: InjectedDisk) -> None:
        self._real = real
        self._disk = disk

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        room = max(0, self._disk.free_bytes())
        if len(view) > room:
            if room:
                self._real.write(view[:room])
                self._real.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = self._real.write(view)
        self._real.flush()  # counted at once (st_size), as a disk counts its blocks
        return len(view) if n is None else int(n)

    def __enter__(self) -> QuotaFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._real.close()

    def __iter__(self) -> Iterator[Any]:
        return iter(self._real)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


class InjectedDisk:
    def __init__(self, root: Path, size_bytes: int, monkeypatch: pytest.MonkeyPatch) -> None:
        self.root = root.resolve()
        self.size = size_bytes
        self.deny = False  # True: opening a file for writing is refused (EACCES)
        real_open = builtins.open
        real_usage = shutil.disk_usage

        def fake_open(file: Any, mode: str = "r", *args: Any, **kw: Any) -> Any:
            writing = isinstance(file, str | Path) and any(m in mode for m in "wax+")
            if writing and self._inside(Path(file)):
                if self.deny:
                    raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(file))
                return QuotaFile(real_open(file, mode, *args, **kw), self)
            return real_open(file, mode, *args, **kw)

        def fake_usage(path: Any) -> Any:
            if self._inside(Path(path)):
                free = max(0, self.free_bytes())
                return shutil._ntuple_diskusage(self.size, self.size - free, free)  # type: ignore[attr-defined]
            return real_usage(path)

        monkeypatch.setattr(builtins, "open", fake_open)
        monkeypatch.setattr(io, "open", fake_open)
        monkeypatch.setattr(shutil, "disk_usage", fake_usage)

    def _inside(self, path: Path) -> bool:
        p = Path(os.path.abspath(path))
        return p == self.root or self.root in p.parents

    def free_bytes(self) -> int:
        used = 0
        for base, _, files in os.walk(self.root):
            for name in files:
                try:
                    used += os.stat(os.path.join(base, name)).st_size
                except OSError:
                    pass
        return self.size - used


@pytest.fixture(params=["tmpfs", "injected"])
def small_disk(
    request: pytest.FixtureRequest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[Path]:
    """A directory on a 15 MB file system that fills."""
    root = tmp_path / "disk"
    root.mkdir()
    if request.param == "injected":
        InjectedDisk(root, DISK_MB * 1_000_000, monkeypatch)
        yield root
        return
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mount = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={DISK_MB}m", "tmpfs", str(root)],
        capture_output=True,
        text=True,
    )
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mount.stderr.strip()}")
    try:
        yield root
    finally:
        subprocess.run(["umount", "-l", str(root)], capture_output=True)


def _tick(i: int) -> TickRecord:
    return TickRecord(
        seq=i, source="sim", t_s=0.1 * i, clock_s=0.1 * i, wall_time=time.time(), phase="approach"
    )


class _Raw(RawPair):
    """A tick's raw side with a stereo pair (what the frame writer records)."""

    def __init__(self, rng: np.random.Generator) -> None:
        # noise: ≈ 80 KB a PNG, 160 KB a pair, whatever the compression
        self.left_image = rng.integers(0, 256, (256, 320), dtype=np.uint8)
        self.right_image = rng.integers(0, 256, (256, 320), dtype=np.uint8)


def _recorder_client(rec: Any) -> TestClient:
    """The real recording router over ``rec`` (no tick loop, no viser)."""
    app = FastAPI()
    app.include_router(recording_router.router, prefix="/api/v1")
    app.state.aar = SimpleNamespace(recorder=rec, settings=SimpleNamespace(token=None))
    return TestClient(app)


def _record_until_stopped(c: TestClient, rec: Any, rec_id: str, timeout: float = 60.0) -> dict:
    """Ticks with stereo pairs, paced for the frame writer, until the recording stops."""
    rng = np.random.default_rng(1)
    deadline = time.monotonic() + timeout
    i = 0
    while time.monotonic() < deadline:
        rec.on_tick(_tick(i), _Raw(rng))
        i += 1
        time.sleep(0.03)
        if i % 5 == 0:
            info = c.get(f"/api/v1/recordings/{rec_id}").json()
            if not info["active"]:
                return dict(info)
    raise AssertionError("the recording did not stop on a full disk")


def _fill(path: Path) -> None:
    """Write ``path`` until the disk is full."""
    with open(path, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC


def _free_mb(path: Path) -> float:
    return shutil.disk_usage(path).free / 1e6


def test_recording_on_a_full_disk_fails_cleanly_and_the_next_one_starts(
    small_disk: Path,
) -> None:
    """ENOSPC while recording frames: stopped as failed with the reason, telemetry kept and
    downloadable, JSON answers (never a plain-text 500), the next start 507 until space is back."""
    # no free-space floor while it fills: with one, the watchdog may stop it (complete, "under
    # the floor") before a write meets ENOSPC — a race under load; the floor is set after
    rec = Recorder(small_disk / "rec", max_s=120, max_mb=100, max_frames_mb=100, min_free_mb=0)
    with _recorder_client(rec) as c:
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 200, r.text
        rec_id = r.json()["id"]
        info = _record_until_stopped(c, rec, rec_id)
        assert info["status"] == "failed", info
        assert "No space left on device" in info["stop_reason"], info
        assert info["frame_pairs"] > 20, info  # what was written is kept
        # listed as failed, not active; stop answers a JSON 409 (it is stopped already)
        listed = {x["id"]: x for x in c.get("/api/v1/recordings").json()}
        assert listed[rec_id]["status"] == "failed" and not listed[rec_id]["active"]
        r = c.post("/api/v1/recording/stop")
        assert r.status_code == 409 and r.json()["detail"] == "no active recording"
        # the telemetry is downloadable: every complete record, no torn last line
        r = c.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl")
        assert r.status_code == 200, r.text
        lines = r.text.splitlines()
        assert len(lines) == info["ticks"] > 0 and all(json.loads(x)["seq"] >= 0 for x in lines)
        # the disk is still full: the next frame recording answers a JSON 507 with the reason
        assert _free_mb(small_disk) < 1
        rec.min_free_mb = 1
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 507, r.text
        assert "under the floor of 1 MB" in r.json()["detail"]
        assert rec.active is None
        # space is back (the frames deleted): it starts, and stops complete
        shutil.rmtree(small_disk / "rec" / f"{rec_id}.frames")
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 200, r.text
        rec.on_tick(_tick(0), _Raw(np.random.default_rng(2)))
        time.sleep(0.3)
        done = c.post("/api/v1/recording/stop").json()
        assert done["status"] == "complete" and done["frame_pairs"] == 1, done
        # the failed recording's metadata is on disk by then
        meta = json.loads((small_disk / "rec" / f"{rec_id}.json").read_text())
        assert meta["status"] == "failed" and "No space left" in meta["stop_reason"]


def test_full_disk_refuses_to_start_with_the_reason(small_disk: Path) -> None:
    """Nothing can be written: a JSON 507 naming the error; under the floor: 507 naming it."""
    rec = Recorder(small_disk / "rec", max_s=120, min_free_mb=20)  # more than the disk
    with _recorder_client(rec) as c:
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 507 and "AAR_RECORDING_MIN_FREE_MB" in r.json()["detail"]
        _fill(small_disk / "filler")
    rec = Recorder(small_disk / "rec", max_s=120)
    with _recorder_client(rec) as c:
        r = c.post("/api/v1/recording/start")
        assert r.status_code == 507, r.text
        assert "No space left on device" in r.json()["detail"], r.text
        assert rec.active is None and c.get("/api/v1/recordings").json() == []
        (small_disk / "filler").unlink()
        assert c.post("/api/v1/recording/start").status_code == 200
        assert c.post("/api/v1/recording/stop").json()["status"] == "complete"


def test_recordings_directory_removed_while_recording(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "rec", max_s=120)
    with _recorder_client(rec) as c:
        rec_id = c.post("/api/v1/recording/start").json()["id"]
        for i in range(5):
            rec.on_tick(_tick(i))
        shutil.rmtree(tmp_path / "rec")
        r = c.post("/api/v1/recording/stop")
        assert r.status_code == 200, r.text
        info = r.json()
        assert info["status"] == "failed" and "No such file or directory" in info["stop_reason"]
        r = c.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl")
        assert r.status_code == 404 and "missing" in r.json()["detail"]
        # the next one recreates the directory
        r = c.post("/api/v1/recording/start")
        assert r.status_code == 200, r.text
        rec.on_tick(_tick(0))
        assert c.post("/api/v1/recording/stop").json()["status"] == "complete"


def test_unwritable_directory_fails_the_recording_and_keeps_its_metadata(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """EACCES (the directory made unwritable while recording; injected: the tests run as
    root): the frame writer's next file fails, the recording stops as failed, its final
    metadata (refused too) is served from memory and written once the directory is writable."""
    disk = InjectedDisk(tmp_path, 10**9, monkeypatch)
    rec = Recorder(tmp_path / "rec", max_s=120)
    with _recorder_client(rec) as c:
        rec_id = c.post("/api/v1/recording/start?frames=true").json()["id"]
        rng = np.random.default_rng(3)
        for i in range(3):
            rec.on_tick(_tick(i), _Raw(rng))
            time.sleep(0.2)
        disk.deny = True
        info = _record_until_stopped(c, rec, rec_id)
        assert info["status"] == "failed" and "Permission denied" in info["stop_reason"], info
        assert info["frame_pairs"] >= 3 and info["ticks"] >= 4
        on_disk = json.loads((tmp_path / "rec" / f"{rec_id}.json").read_text())
        assert on_disk["status"] == "recording"  # the disk refused the final metadata
        r = c.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl")
        assert r.status_code == 200 and len(r.text.splitlines()) == info["ticks"]
        r = c.post("/api/v1/recording/start")
        assert r.status_code == 503 and "Permission denied" in r.json()["detail"], r.text
        disk.deny = False
        assert c.post("/api/v1/recording/start").status_code == 200
        on_disk = json.loads((tmp_path / "rec" / f"{rec_id}.json").read_text())
        assert on_disk["status"] == "failed" and on_disk["stop_reason"] == info["stop_reason"]
        assert c.post("/api/v1/recording/stop").json()["status"] == "complete"
