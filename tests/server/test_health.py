"""``/healthz``'s tick-loop component turns ``degraded`` with the reason when the loop is
dead or its source has stopped producing, and back to ``ok`` when it runs again."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.server.main import create_app
from tests.support.fake_sim import FakeSim, FakeSimState
from tests.support.inline_sim import inline_sim
from tests.support.service_settings import service_settings
from tests.support.waiting import wait_until


def _tick_loop(c: TestClient) -> tuple[str, dict[str, object]]:
    h = c.get("/api/v1/healthz").json()
    comp = next(x for x in h["components"] if x["name"] == "tick_loop")
    return h["status"], comp


def test_a_dead_tick_loop_thread_is_degraded(tmp_path: Path) -> None:
    settings = service_settings(tmp_path, sim_auto_restart_s=None)
    app = create_app(settings, source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)))
    with TestClient(app) as c:
        loop = c.app.state.aar.loop  # type: ignore[attr-defined]
        wait_until(lambda: loop.ticks >= 5, 10.0, "the loop did not tick")
        assert _tick_loop(c)[0] == "ok"
        loop.stop()  # the thread ends: nothing ticks any more
        status, comp = _tick_loop(c)
        assert status == "degraded" and comp["status"] == "degraded"
        assert comp["reason"] == "the tick loop thread is not running"
        loop.start()
        wait_until(lambda: _tick_loop(c)[0] == "ok", 10.0, "healthz did not recover")


class _Stalling(FakeSim):
    """Steps normally until ``stall`` is set, then blocks inside ``step`` (a hung simulation)."""

    stall = threading.Event()
    release = threading.Event()

    def step(self) -> FakeSimState:
        if self.stall.is_set():
            self.release.wait(30.0)
        return super().step()


def test_a_source_that_stops_producing_is_degraded(tmp_path: Path) -> None:
    _Stalling.stall.clear()
    _Stalling.release.clear()
    settings = service_settings(tmp_path, sim_auto_restart_s=None)
    app = create_app(settings, source_factory=inline_sim(lambda cfg, cal: _Stalling(cfg, cal)))
    with TestClient(app) as c:
        loop = c.app.state.aar.loop  # type: ignore[attr-defined]
        wait_until(lambda: loop.ticks >= 5, 10.0, "the loop did not tick")
        _Stalling.stall.set()
        t0 = time.monotonic()
        wait_until(lambda: _tick_loop(c)[0] == "degraded", 15.0, "a hung source stayed ok")
        assert time.monotonic() - t0 >= 4.0  # not before the 5 s without a tick
        status, comp = _tick_loop(c)
        assert str(comp["reason"]).startswith("no tick for ")
        _Stalling.stall.clear()
        _Stalling.release.set()
        wait_until(lambda: _tick_loop(c)[0] == "ok", 10.0, "healthz did not recover")
