"""The service's CPU work in worker processes: the simulation (``app.service.sim_worker``) and
the uploads (``app.service.upload_pool``), as the default app runs them."""

from __future__ import annotations

import asyncio
import os
import signal
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.server.main import create_app
from app.service.settings import Settings
from app.service.sim_worker import image_ring, proxy
from app.service.upload_pool import ExecutorFactory
from tests.support.service_settings import service_settings
from tests.support.upload_executor import thread_uploads
from tests.support.waiting import wait_until

REPO = Path(__file__).resolve().parents[2]
PAIR = REPO / "sample_data" / "pair_1000mm"


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(tmp_path, **{"sim_auto_restart_s": None, **kw})


@pytest.fixture
def service(tmp_path: Path) -> Iterator[tuple[TestClient, Any]]:
    """The default app (no injected source): the simulation in a worker process."""
    with TestClient(create_app(_settings(tmp_path))) as c:
        yield c, c.app.state.aar  # type: ignore[attr-defined]


def test_default_app_steps_the_simulation_in_a_worker_process(
    service: tuple[TestClient, Any],
) -> None:
    c, st = service
    worker = st.sim_worker
    assert worker is not None and worker.alive
    assert worker.pid is not None and worker.pid != os.getpid()
    assert worker.ping() == worker.pid
    raws: list[Any] = []
    st.bus.subscribe(lambda record, raw: raws.append((record, raw)))
    wait_until(lambda: len(raws) >= 8, 10, "ticks from the worker")
    h = c.get("/api/v1/healthz").json()
    assert h["status"] == "ok" and h["sim_running"] and h["ticks"] >= 8 and h["errors"] == 0
    record, raw = raws[-1]
    assert record.source == "sim" and record.t_s > 0 and record.uav_state is not None
    assert record.pose is not None and record.led_truth_cam_mm is not None
    assert record.timings_ms["sim"] > 0  # the worker's step time rides along
    # the camera images come through shared memory, read on demand (here, at once)
    left, right = raw.left_image, raw.right_image
    assert left is not None and right is not None
    assert left.shape == (1024, 1280) and right.shape == (1024, 1280) and left.dtype == np.uint8
    assert int(left.max()) > 200  # the LEDs are in the picture
    # a slot overwritten long ago reads as None (the dashboard keeps its last image)
    _, old = raws[0]
    wait_until(lambda: len(raws) >= 8 + 2 * image_ring.RING_SLOTS, 10, "more ticks")
    if old._images is None:  # not read yet
        assert old.left_image is None
    # shutting the service down stops the worker and frees the shared memory
    ring = worker._ring
    assert ring is not None
    name = ring.name
    c.__exit__(None, None, None)
    assert not worker.alive and worker._ring is None
    assert not Path("/dev/shm", name).exists()


def test_refused_config_is_422_and_the_old_simulation_keeps_stepping(
    service: tuple[TestClient, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    from app.sim.docking import DockingConfig

    c, st = service
    loop = st.loop
    # a config the parent lets through but the simulation (in the worker) refuses
    real = proxy.docking_config

    def refused_for_seed_77(config: Any) -> Any:
        dcfg = real(config)
        return replace(dcfg, camera_hz=1e6) if config.seed == 77 else dcfg

    monkeypatch.setattr(proxy, "docking_config", refused_for_seed_77)
    monkeypatch.setattr(DockingConfig, "validate", lambda self: None)  # only here, the parent
    wait_until(lambda: loop.ticks >= 3, 10, "first ticks")
    run0, config0, pid0 = loop.run, loop.config, st.sim_worker.pid
    t0 = loop.bus.latest.t_s
    r = c.put("/api/v1/sim/config", json={"seed": 77})
    assert r.status_code == 422, r.text
    assert "simulation rejected the config" in r.json()["detail"]
    assert "camera_hz" in r.json()["detail"]  # the worker's own ValueError
    assert loop.config == config0 and loop.run == run0 and st.sim_worker.pid == pid0
    n = loop.ticks
    wait_until(lambda: loop.ticks >= n + 5, 10, "ticks after the refusal")
    assert loop.bus.latest.t_s > t0 and loop.bus.latest.run == run0  # the same run goes on
    assert loop.errors == 0
    # an accepted one: a new run, in the same worker
    r = c.put("/api/v1/sim/config", json={"seed": 5})
    assert r.status_code == 200 and loop.run == run0 + 1 and st.sim_worker.pid == pid0
    wait_until(lambda: loop.bus.latest.run == run0 + 1, 10, "ticks of the new run")
    assert st.sim_worker.spawns == 1


def test_the_groups_sigterm_leaves_the_worker_to_the_parent(
    service: tuple[TestClient, Any],
) -> None:
    """A service manager's SIGTERM to the whole process group (systemd, ``timeout``) does not
    kill the worker: the parent stops it at its own shutdown, nothing is lost or respawned."""
    c, st = service
    loop, worker = st.loop, st.sim_worker
    wait_until(lambda: loop.ticks >= 3, 10, "first ticks")
    pid0 = worker.pid
    os.kill(pid0, signal.SIGTERM)
    n = loop.ticks
    wait_until(lambda: loop.ticks >= n + 10, 10, "ticks after the SIGTERM")
    assert worker.ping() == pid0 and worker.restarts == 0 and worker.spawns == 1
    assert loop.errors == 0


def test_killed_worker_is_replaced_and_ticks_resume(service: tuple[TestClient, Any]) -> None:
    c, st = service
    loop, worker = st.loop, st.sim_worker
    wait_until(lambda: loop.ticks >= 3, 10, "first ticks")
    pid0, run0 = worker.pid, loop.run
    os.kill(pid0, signal.SIGKILL)
    wait_until(lambda: loop.errors >= 1, 10, "the loss to be noticed")
    wait_until(lambda: loop.bus.latest.run > run0, 15, "ticks from the new worker")
    assert worker.pid is not None and worker.pid not in (pid0, os.getpid())
    assert worker.restarts == 1 and worker.spawns == 2
    n = loop.ticks
    wait_until(lambda: loop.ticks >= n + 5, 10, "steady ticks")
    h = c.get("/api/v1/healthz").json()
    assert h["status"] == "ok" and h["sim_running"] and h["errors"] == 1
    assert "worker" in h["last_error"]
    assert loop.bus.latest.t_s < 2.0  # a new run: the simulation restarted from its start
    assert "aar_sim_worker_restarts_total 1" in c.get("/api/v1/metrics").text


def test_a_hung_worker_times_out_and_is_replaced(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path, sim_step_timeout_s=1.0))) as c:
        st = c.app.state.aar  # type: ignore[attr-defined]
        loop, worker = st.loop, st.sim_worker
        wait_until(lambda: loop.ticks >= 3, 10, "first ticks")
        pid0, run0 = worker.pid, loop.run
        os.kill(pid0, signal.SIGSTOP)  # alive, but never answers
        t0 = time.monotonic()
        try:
            wait_until(lambda: loop.errors >= 1, 20, "the step timeout")
        finally:
            if worker.pid == pid0:  # pragma: no cover - not replaced: do not leave it stopped
                os.kill(pid0, signal.SIGKILL)
        # the 1 s timeout + a respawn (≈ 1–2 s, more on a loaded machine), not a hang
        assert time.monotonic() - t0 < 12.0
        assert "no answer within 1 s" in (loop.last_error or "")
        wait_until(lambda: loop.bus.latest.run > run0, 15, "ticks from the new worker")
        assert worker.pid != pid0 and worker.restarts == 1
        assert not Path(f"/proc/{pid0}").exists() or "Z" in Path(f"/proc/{pid0}/stat").read_text()


def _in_process_result(matcher: str) -> Any:
    from app.geometry.calibration import StereoCalibration
    from app.service.settings import DEFAULT_CALIBRATION
    from app.service.upload_pool import decode_upload_image
    from app.vision.pipeline import NavigationPipeline, PipelineConfig

    calib = StereoCalibration.load(DEFAULT_CALIBRATION)
    left = decode_upload_image((PAIR / "left.png").read_bytes(), "left")
    right = decode_upload_image((PAIR / "right.png").read_bytes(), "right")
    return NavigationPipeline(calib, PipelineConfig(matcher=matcher)).process(left, right)  # type: ignore[arg-type]


def test_upload_in_a_worker_process_equals_the_in_process_pipeline(tmp_path: Path) -> None:
    settings = _settings(tmp_path, sim_autostart=False)
    files = {
        "left": ("l.png", (PAIR / "left.png").read_bytes()),
        "right": ("r.png", (PAIR / "right.png").read_bytes()),
    }
    with TestClient(create_app(settings)) as c:
        st = c.app.state.aar  # type: ignore[attr-defined]
        got = {}
        for matcher in ("epipolar", "paper"):
            r = c.post("/api/v1/stereo", files=files, data={"matcher": matcher})
            assert r.status_code == 200, r.text
            got[matcher] = r.json()
        pids = st.upload_pool.pids()
        assert pids and os.getpid() not in pids
        state = c.get("/api/v1/state").json()
        assert state["source"] == "upload"
    for matcher, res in got.items():
        ref = _in_process_result(matcher)
        assert res["lock"] == ref.lock and res["reason"] == ref.reason
        assert [led["id"] for led in res["leds"]] == [led.id for led in ref.leds]
        for a, b in zip(res["leds"], ref.leds, strict=True):
            np.testing.assert_allclose(a["xyz_mm"], b.xyz_mm, rtol=0, atol=1e-9)
            np.testing.assert_allclose(a["left_px"], b.left_px, rtol=0, atol=1e-9)
            np.testing.assert_allclose(a["right_px"], b.right_px, rtol=0, atol=1e-9)
        assert ref.drogue is not None
        np.testing.assert_allclose(
            res["drogue"]["center_mm"], ref.drogue.center_mm, rtol=0, atol=1e-9
        )


def test_upload_errors_are_the_same_with_either_executor(tmp_path: Path) -> None:
    ok = (PAIR / "left.png").read_bytes()
    broken = ok[:200]  # a valid PNG header (passes the guard), no image data
    answers = []
    for executor in (None, thread_uploads):  # the default worker processes, then threads
        settings = _settings(tmp_path, sim_autostart=False)
        with TestClient(create_app(settings, upload_executor=executor)) as c:
            r = c.post("/api/v1/stereo", files={"left": ("l.png", ok), "right": ("r.png", broken)})
            answers.append((r.status_code, r.json()))
    assert answers[0] == answers[1]
    assert answers[0][0] == 400 and "right: could not decode" in answers[0][1]["detail"]


@pytest.mark.parametrize("executor", [None, thread_uploads], ids=["processes", "threads"])
def test_the_route_runs_process_upload_in_the_pool_whatever_its_executor(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, executor: ExecutorFactory | None
) -> None:
    """One path: ``POST /stereo`` hands ``process_upload`` to the ``UploadPool``; only where it
    runs differs (worker processes by default, the injected executor's threads)."""
    from app.service import upload_pool

    ran: list[object] = []
    real_run = upload_pool.UploadPool.run

    async def spy_run(self: Any, fn: Any, *args: Any, **kwargs: Any) -> Any:
        ran.append(fn)
        return await real_run(self, fn, *args, **kwargs)

    decoded_in: list[str] = []  # seen only where the work runs in this process
    real_decode = upload_pool.decode_upload_image

    def spy_decode(data: bytes, name: str) -> np.ndarray:
        decoded_in.append(threading.current_thread().name)
        return real_decode(data, name)

    monkeypatch.setattr(upload_pool.UploadPool, "run", spy_run)
    monkeypatch.setattr(upload_pool, "decode_upload_image", spy_decode)
    files = {
        "left": ("l.png", (PAIR / "left.png").read_bytes()),
        "right": ("r.png", (PAIR / "right.png").read_bytes()),
    }
    with TestClient(
        create_app(_settings(tmp_path, sim_autostart=False), upload_executor=executor)
    ) as c:
        r = c.post("/api/v1/stereo", files=files)
        assert r.status_code == 200 and r.json()["lock"], r.text
        pids = c.app.state.aar.upload_pool.pids()  # type: ignore[attr-defined]
    assert ran == [upload_pool.process_upload]
    if executor is None:  # decoded in a worker process: this process's spy saw nothing
        assert pids and os.getpid() not in pids and decoded_in == []
    else:
        assert pids == []
        assert len(decoded_in) == 2
        assert all(name.startswith("aar-upload-test") for name in decoded_in), decoded_in


def test_upload_pool_with_a_thread_executor_answers_in_this_process() -> None:
    from app.service.upload_pool import UploadPool

    pool = UploadPool(2, executor_factory=thread_uploads)
    try:
        assert asyncio.run(pool.run(os.getpid)) == os.getpid()
        thread = asyncio.run(pool.run(threading.current_thread))
        assert thread is not threading.main_thread() and thread.name.startswith("aar-upload")
        assert pool.pids() == [] and pool.submitted == 2 and pool.restarts == 0
    finally:
        pool.shutdown()


def test_a_broken_injected_executor_is_replaced() -> None:
    """Any ``BrokenExecutor`` (here a thread pool whose initializer fails), not only a process
    pool's, is answered ``UploadWorkerCrashed`` and the executor replaced."""
    from app.service.upload_pool import UploadPool, UploadWorkerCrashed

    made: list[ThreadPoolExecutor] = []

    def fail() -> None:
        raise RuntimeError("initializer failed")

    def factory(max_workers: int) -> ThreadPoolExecutor:
        made.append(ThreadPoolExecutor(max_workers, initializer=fail if not made else None))
        return made[-1]

    pool = UploadPool(1, executor_factory=factory)
    try:
        with pytest.raises(UploadWorkerCrashed):
            asyncio.run(pool.run(abs, -1))
        assert pool.restarts == 1 and len(made) == 2
        assert asyncio.run(pool.run(abs, -2)) == 2  # the new executor answers
    finally:
        pool.shutdown()


def test_upload_pool_survives_a_dead_worker() -> None:
    from app.service.upload_pool import UploadPool, UploadWorkerCrashed

    pool = UploadPool(1, nice=0)
    try:
        assert asyncio.run(pool.run(os.getpid)) != os.getpid()
        with pytest.raises(UploadWorkerCrashed):
            asyncio.run(pool.run(os._exit, 3))
        assert pool.restarts == 1
        assert asyncio.run(pool.run(abs, -2)) == 2  # a new pool answers
    finally:
        pool.shutdown()


def test_without_shared_memory_images_travel_in_the_pipe_at_the_image_rate() -> None:
    from app.geometry.calibration import StereoCalibration
    from app.service.settings import DEFAULT_CALIBRATION
    from app.sim.sim_config import SimConfig

    factory = proxy.process_source_factory(image_hz=0.5, shared_images=False)
    try:
        src = factory(SimConfig(), StereoCalibration.load(DEFAULT_CALIBRATION))
        ticks = [src.step() for _ in range(6)]  # far quicker than 2 s
    finally:
        factory.close()
    with_images = [t.left_image is not None for t in ticks]
    assert with_images == [True] + [False] * 5
    right0 = ticks[0].right_image
    assert right0 is not None and right0.shape == (1024, 1280)
    assert all(t.state.pose is not None for t in ticks)  # every tick's data, only not its images
