"""API tests (FastAPI TestClient with the lifespan on) with a tiny fake step source.

The fake lives here only: the product drives ``app.sim.docking.DockingSimulation``
(see ``tests/server/test_sim.py`` for the real stream).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.server.main import create_app
from app.service.clock import FakeClock
from app.service.settings import Settings
from app.service.tick_loop import TickLoop
from app.sim.sim_config import SimConfig
from tests.support.fake_sim import FakeSim
from tests.support.inline_sim import inline_sim
from tests.support.service_settings import service_settings

REPO = Path(__file__).resolve().parents[2]


def _settings(tmp_path: Path, **kw: object) -> Settings:
    return service_settings(tmp_path, **{"tick_hz": 30.0, "sim_auto_restart_s": None, **kw})


@pytest.fixture
def client(tmp_path: Path):
    app = create_app(
        _settings(tmp_path), source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal))
    )
    with TestClient(app) as c:
        yield c


def _png(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


# ---- tick loop (deterministic, fake clock) ----------------------------------------------
def test_tick_loop_fixed_rate_with_fake_clock_drops_late_ticks() -> None:
    clock = FakeClock()
    cfg = SimConfig(tick_hz=10.0)
    # every step costs 2.5 periods of clock time → after each tick two deadlines are missed
    loop = TickLoop(
        cfg,
        None,
        clock=clock,
        source_factory=inline_sim(
            lambda c, k: FakeSim(c, k, clock=clock, step_cost_s=0.25), clock=clock
        ),
    )
    loop.start_sim()
    got = []
    loop.bus.subscribe(lambda rec, raw: got.append(rec))
    loop.run_iterations(30)
    assert loop.ticks == len(got) > 0
    # each tick costs 2.5 periods: every deadline that passed is either ticked or dropped,
    # none is queued, so ticks + dropped = elapsed / period and dropped/ticks → 1.5
    elapsed_deadlines = clock.now() / 0.1
    assert loop.ticks + loop.dropped == pytest.approx(elapsed_deadlines, abs=2)
    assert loop.dropped / loop.ticks == pytest.approx(1.5, abs=0.1)
    # records are published in order with increasing seq
    assert [r.seq for r in got] == sorted(r.seq for r in got)


def test_tick_loop_on_time_drops_nothing_and_keeps_rate() -> None:
    clock = FakeClock()
    loop = TickLoop(
        SimConfig(tick_hz=20.0),
        None,
        clock=clock,
        source_factory=inline_sim(lambda c, k: FakeSim(c, k), clock=clock),
    )
    loop.start_sim()
    loop.run_iterations(200)
    assert loop.dropped == 0
    # fake time advanced only by sleeping: ticks = elapsed × rate (+1 for t=0)
    assert loop.ticks == pytest.approx(clock.now() * 20.0 + 1, abs=1)
    assert loop.tick_rate_hz() == pytest.approx(20.0, rel=1e-6)


def test_stopped_simulation_counts_no_dropped_ticks() -> None:
    """Deadlines that pass while the simulation is stopped (the service ran with --no-sim, or
    the loop thread was late) are not dropped ticks: healthz must not report drops of a
    simulation that is not running; once it runs, a late deadline is counted again."""
    clock = FakeClock()
    loop = TickLoop(
        SimConfig(tick_hz=20.0),
        None,
        clock=clock,
        source_factory=inline_sim(lambda c, k: FakeSim(c, k), clock=clock),
    )
    loop.run_iterations(5)
    clock.advance(1.0)  # 20 deadlines pass unserved while stopped
    loop.run_iterations(5)
    assert loop.dropped == 0 and loop.ticks == 0
    loop.start_sim()
    loop.run_iterations(20)
    clock.advance(0.5)  # the running loop 10 periods late: 9 deadlines dropped, the 10th served
    loop.run_iterations(5)
    assert loop.dropped == 9


def test_tick_loop_auto_restart_after_done() -> None:
    clock = FakeClock()
    loop = TickLoop(
        SimConfig(tick_hz=10.0, seed=3),
        None,
        clock=clock,
        auto_restart_s=1.0,
        source_factory=inline_sim(lambda c, k: FakeSim(c, k, steps=5), clock=clock),
    )
    loop.start_sim()
    runs = set()
    loop.bus.subscribe(lambda rec, raw: runs.add(rec.run))
    loop.run_iterations(200)
    assert len(runs) >= 2
    assert loop.config.seed > 3  # the next run uses the next seed


# ---- REST ---------------------------------------------------------------------------------
def test_state_history_health_metrics(client: TestClient) -> None:
    deadline = time.time() + 5
    while time.time() < deadline and client.get("/api/v1/healthz").json()["ticks"] < 10:
        time.sleep(0.05)
    h = client.get("/api/v1/healthz").json()
    assert h["loop_alive"] and h["sim_running"] and h["ticks"] >= 10
    assert h["status"] == "ok"
    s = client.get("/api/v1/state")
    assert s.status_code == 200
    rec = s.json()
    assert rec["source"] == "sim" and rec["lock"] is True
    assert rec["control"]["throttle"] == pytest.approx(0.5)
    hist = client.get("/api/v1/history", params={"seconds": 5}).json()
    assert len(hist) >= 10
    assert [r["seq"] for r in hist] == sorted(r["seq"] for r in hist)
    assert client.get("/api/v1/history", params={"seconds": -1}).status_code == 422
    assert client.get("/api/v1/history", params={"seconds": 1e6}).status_code == 422
    m = client.get("/api/v1/metrics")
    assert m.status_code == 200 and m.headers["content-type"].startswith("text/plain")
    assert "aar_ticks_total" in m.text and "aar_ticks_dropped_total" in m.text
    assert 'aar_stage_latency_ms{quantile="0.5",stage="step"}' in m.text
    cfg = client.get("/api/v1/config").json()
    assert cfg["image_size"] == [1280, 1024] and cfg["viser_url"] is None


def test_sim_start_stop_reset_and_config_validation(client: TestClient) -> None:
    r = client.post("/api/v1/sim/stop")
    assert r.status_code == 200 and r.json()["running"] is False
    n0 = client.get("/api/v1/healthz").json()["ticks"]
    time.sleep(0.3)
    assert client.get("/api/v1/healthz").json()["ticks"] - n0 <= 1
    run0 = client.get("/api/v1/sim").json()["run"]
    assert client.post("/api/v1/sim/reset").json()["run"] == run0 + 1
    assert client.post("/api/v1/sim/start").json()["running"] is True

    good = client.put(
        "/api/v1/sim/config",
        json={"turbulence": "moderate", "closure_speed_mps": 1.5, "led_dropout": [4, 2]},
    )
    assert good.status_code == 200
    body = good.json()
    assert body["turbulence"] == "moderate" and body["led_dropout"] == [2, 4]
    assert client.get("/api/v1/sim/config").json()["closure_speed_mps"] == 1.5
    for bad in (
        {"turbulence": "hurricane"},
        {"closure_speed_mps": 0.0},
        {"closure_speed_mps": 99},
        {"noise_sigma": -1},
        {"clutter": 1000},
        {"led_dropout": [0]},
        {"led_dropout": [6]},
        {"led_dropout": [1, 1]},
        {"tick_hz": 0.5},
        {"seed": -2},
    ):
        r = client.put("/api/v1/sim/config", json=bad)
        assert r.status_code == 422, bad
        assert "detail" in r.json()
    # nothing changed by the rejected updates
    assert client.get("/api/v1/sim/config").json()["turbulence"] == "moderate"


def test_calibration_put_validation_and_rollback(client: TestClient) -> None:
    orig = client.get("/api/v1/calibration").json()
    assert orig["image_size"] == [1280, 1024]
    bad = json.loads(json.dumps(orig))
    bad["left"]["K"] = [[1, 0], [0, 1]]
    r = client.put("/api/v1/calibration", json=bad)
    assert r.status_code == 422 and r.json()["field"] == "left.K" and "left.K" in r.json()["detail"]
    bad2 = json.loads(json.dumps(orig))
    del bad2["T"]
    r = client.put("/api/v1/calibration", json=bad2)
    assert r.status_code == 422 and r.json()["field"] == "T"
    assert client.post("/api/v1/calibration/rollback").status_code == 409
    new = json.loads(json.dumps(orig))
    new["T"] = [-120.0, 0.0, -20.0]
    assert client.put("/api/v1/calibration", json=new).status_code == 200
    assert client.get("/api/v1/calibration").json()["T"] == [-120.0, 0.0, -20.0]
    r = client.post("/api/v1/calibration/rollback")
    assert r.status_code == 200
    assert client.get("/api/v1/calibration").json()["T"] == orig["T"]


def test_bad_uploads_are_4xx(tmp_path: Path) -> None:
    app = create_app(
        _settings(tmp_path, max_upload_mb=0.5),
        source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)),
    )
    ok = _png(np.zeros((1024, 1280), np.uint8))
    with TestClient(app) as c:

        def post(left: bytes, right: bytes, **data: str):
            return c.post(
                "/api/v1/stereo",
                files={"left": ("l.png", left), "right": ("r.png", right)},
                data=data,
            )

        cases = {
            "corrupt": post(b"\x89PNG\r\n\x1a\nnot really", ok),
            "text": post(b"hello", ok),
            "empty": post(b"", ok),
            "mismatched": post(ok, _png(np.zeros((1000, 1280), np.uint8))),
            "wrong size": post(
                _png(np.zeros((480, 640), np.uint8)), _png(np.zeros((480, 640), np.uint8))
            ),
            "oversized": post(
                np.random.default_rng(0).integers(0, 255, 800_000, dtype=np.uint8).tobytes(), ok
            ),
            "bad matcher": post(ok, ok, matcher="sift"),
        }
        missing = c.post("/api/v1/stereo", files={"left": ("l.png", ok)})
    expected = {
        "corrupt": 400,
        "text": 400,
        "empty": 400,
        "mismatched": 422,
        "wrong size": 422,
        "oversized": 413,
        "bad matcher": 422,
    }
    for name, resp in cases.items():
        assert resp.status_code == expected[name], (name, resp.status_code, resp.text)
        assert resp.json()["detail"], name
    assert missing.status_code == 422


def test_token_protects_mutations_only(tmp_path: Path) -> None:
    app = create_app(
        _settings(tmp_path, token="s3cret"),
        source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)),
    )
    with TestClient(app) as c:
        assert c.post("/api/v1/sim/stop").status_code == 401
        assert (
            c.post("/api/v1/sim/stop", headers={"Authorization": "Bearer nope"}).status_code == 401
        )
        assert c.put("/api/v1/sim/config", json={"seed": 1}).status_code == 401
        assert c.post("/api/v1/recording/start").status_code == 401
        assert (
            c.post("/api/v1/stereo", files={"left": ("l", b"x"), "right": ("r", b"x")}).status_code
            == 401
        )
        assert c.get("/api/v1/sim/config").status_code == 200
        assert c.get("/api/v1/healthz").status_code == 200
        r = c.post("/api/v1/sim/stop", headers={"Authorization": "Bearer s3cret"})
        assert r.status_code == 200 and r.json()["running"] is False
        assert c.get("/api/v1/config").json()["token_required"] is True


def test_websocket_streams_ticks(client: TestClient) -> None:
    with client.websocket_connect("/api/v1/telemetry") as ws:
        recs = [json.loads(ws.receive_text()) for _ in range(12)]
    assert len(recs) == 12
    seqs = [r["seq"] for r in recs]
    assert seqs == sorted(seqs) and len(set(seqs)) == 12
    ts = [r["t_s"] for r in recs]
    assert ts[-1] > ts[0]
    assert all(r["source"] == "sim" and "left_image" not in r for r in recs)


def test_websocket_queue_drops_oldest() -> None:
    import asyncio

    from app.service.telemetry import ClientQueue

    async def run() -> list[str]:
        q = ClientQueue(3)
        for i in range(10):
            q.put(str(i))
        assert q.dropped == 7
        return [q.queue.get_nowait() for _ in range(3)]

    assert asyncio.run(run()) == ["7", "8", "9"]


def test_recording_roundtrip_without_viser(client: TestClient) -> None:
    r = client.post("/api/v1/recording/start")
    assert r.status_code == 200
    rec_id = r.json()["id"]
    assert client.post("/api/v1/recording/start").status_code == 409
    time.sleep(0.5)
    stop = client.post("/api/v1/recording/stop")
    assert stop.status_code == 200 and stop.json()["ticks"] >= 5
    assert client.post("/api/v1/recording/stop").status_code == 409
    lst = client.get("/api/v1/recordings").json()
    assert any(x["id"] == rec_id for x in lst)
    info = client.get(f"/api/v1/recordings/{rec_id}").json()
    assert info["ticks"] == stop.json()["ticks"]
    tele = client.get(f"/api/v1/recordings/{rec_id}/telemetry.jsonl")
    lines = [json.loads(x) for x in tele.text.splitlines()]
    assert len(lines) == info["ticks"]
    assert client.get("/api/v1/recordings/../../etc").status_code == 404
    assert client.get("/api/v1/recordings/nope").status_code == 404


def test_openapi_and_index(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    for path in (
        "/api/v1/stereo",
        "/api/v1/state",
        "/api/v1/history",
        "/api/v1/sim/config",
        "/api/v1/calibration",
        "/api/v1/healthz",
        "/api/v1/recordings",
    ):
        assert path in spec["paths"], path
    assert client.get("/docs").status_code == 200


def test_bad_calibration_file_fails_startup(tmp_path: Path) -> None:
    bad = tmp_path / "cal.json"
    bad.write_text("{}")
    app = create_app(
        _settings(tmp_path, calibration=bad),
        source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)),
    )
    with pytest.raises(Exception, match="calibration field"):
        with TestClient(app):
            pass


def test_settings_env_and_cli_flags_override(monkeypatch: pytest.MonkeyPatch) -> None:
    from app.cli.main import build_parser
    from app.cli.serve import settings_from_args

    monkeypatch.setenv("AAR_PORT", "9100")
    monkeypatch.setenv("AAR_VISER_PORT", "9101")
    monkeypatch.setenv("AAR_TICK_HZ", "20")
    monkeypatch.setenv("AAR_TOKEN", "tok")
    monkeypatch.setenv("AAR_MAX_UPLOAD_MB", "3")
    s = settings_from_args(build_parser().parse_args(["serve"]))
    assert (s.port, s.viser_port, s.tick_hz, s.token, s.max_upload_mb) == (
        9100,
        9101,
        20.0,
        "tok",
        3.0,
    )
    assert s.host == "127.0.0.1"
    s = settings_from_args(
        build_parser().parse_args(
            ["serve", "--port", "9200", "--viser-port", "9201", "--host", "0.0.0.0"]
        )
    )
    assert (s.port, s.viser_port, s.host, s.tick_hz) == (9200, 9201, "0.0.0.0", 20.0)
    monkeypatch.setenv("AAR_TICK_HZ", "-5")
    with pytest.raises(Exception, match="tick_hz"):
        settings_from_args(build_parser().parse_args(["serve"]))


def test_serve_refuses_taken_viser_port(tmp_path: Path) -> None:
    import socket
    import subprocess
    import sys

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        vport = busy.getsockname()[1]
        with socket.socket() as s2:
            s2.bind(("127.0.0.1", 0))
            port = s2.getsockname()[1]
        r = subprocess.run(
            [sys.executable, "-m", "app", "serve", "--port", str(port), "--viser-port", str(vport)],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=REPO,
        )
    assert r.returncode == 2
    assert f"viser port {vport} is in use" in r.stderr
    assert "Traceback" not in r.stderr


def test_config_refused_by_the_simulation_is_422_and_kept(tmp_path: Path) -> None:
    def factory(cfg: SimConfig, cal: object) -> FakeSim:
        if cfg.clutter == 13:
            raise ValueError("clutter 13 is unlucky")
        return FakeSim(cfg, cal)

    with TestClient(create_app(_settings(tmp_path), source_factory=inline_sim(factory))) as c:
        run0 = c.get("/api/v1/sim").json()["run"]
        r = c.put("/api/v1/sim/config", json={"clutter": 13})
        assert r.status_code == 422 and "unlucky" in r.json()["detail"]
        assert c.get("/api/v1/sim/config").json()["clutter"] == 0
        assert c.get("/api/v1/sim").json()["run"] == run0


def test_failing_steps_stop_the_stream_and_show_in_healthz() -> None:
    class Broken(FakeSim):
        def step(self):  # type: ignore[override]
            raise RuntimeError("boom")

    clock = FakeClock()
    loop = TickLoop(
        SimConfig(),
        None,
        clock=clock,
        source_factory=inline_sim(lambda c, k: Broken(c, k), clock=clock),
    )
    loop.start_sim()
    loop.run_iterations(200)
    assert loop.running is False
    assert loop.errors == 10 and loop.last_error == "RuntimeError: boom"
    assert loop.ticks == 0
