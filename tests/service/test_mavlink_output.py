"""The service's MAVLink 2 output (``Settings.mavlink``): a pymavlink listener on UDP loopback
gets HEARTBEATs and one LANDING_TARGET per navigation record, equal to the telemetry,
``position_valid`` 0 while the lock is forced off (every LED switched off), and one STATUSTEXT
per hand-over of the run-time assurance."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pymavlink import mavutil

from app.server.main import create_app
from app.service.settings import Settings
from app.sim.rig_mount import default_mount
from app.streams.landing_target import RigMount
from app.streams.mavlink_link import MavlinkLink  # noqa: F401  (MAVLink 2 dialect first)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _drain(rx, kind: str, seconds: float) -> list:
    out, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        m = rx.recv_match(type=kind, blocking=True, timeout=0.2)
        if m is not None:
            out.append(m)
    return out


def test_landing_targets_follow_the_telemetry(tmp_path: Path) -> None:
    port = _free_udp_port()
    rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
    settings = Settings(  # type: ignore[call-arg]
        viser_enabled=False,
        recordings_dir=tmp_path / "rec",
        sim_auto_restart_s=None,
        mavlink=f"udpout:127.0.0.1:{port}",
        mavlink_sim=True,  # the simulated stream's targets, asked for (SITL)
    )
    try:
        with TestClient(create_app(settings)) as c:
            with c.websocket_connect("/api/v1/telemetry") as ws:
                recs = [json.loads(ws.receive_text()) for _ in range(60)]
            msgs = _drain(rx, "LANDING_TARGET", 1.0)
            stats = c.app.state.aar.mavlink.stats  # type: ignore[attr-defined]
            # forced no-lock: every LED off
            r = c.put("/api/v1/sim/config", json={"led_dropout": [1, 2, 3, 4, 5]})
            assert r.status_code == 200, r.text
            time.sleep(1.0)
            _drain(rx, "LANDING_TARGET", 0.3)  # the ticks around the switch
            dark = _drain(rx, "LANDING_TARGET", 1.5)
            hist = c.get("/api/v1/history", params={"seconds": 1.0}).json()
        heartbeats = _drain(rx, "HEARTBEAT", 0.1)
    finally:
        rx.close()
    # one LANDING_TARGET per record: the telemetry's ticks are all in what was received
    by_time = {m.time_usec: m for m in msgs}
    sent = [rec for rec in recs if round(rec["t_s"] * 1e6) in by_time]
    assert len(sent) >= 0.9 * len(recs), (len(sent), len(recs))
    assert stats.targets >= len(recs) and stats.send_errors == 0
    mount = RigMount.on_airframe(default_mount(settings.sim_plant))
    locked = 0
    for rec in sent:
        m = by_time[round(rec["t_s"] * 1e6)]
        assert m.frame == mavutil.mavlink.MAV_FRAME_BODY_FRD
        assert m.target_num == 255  # simulated: marked
        assert m.position_valid == int(rec["lock"])
        if not rec["lock"]:
            assert (m.x, m.y, m.z, m.distance) == (0.0, 0.0, 0.0, 0.0)
            continue
        locked += 1
        c_mm = np.array(rec["pose"]["drogue"]["center_mm"])
        assert m.distance == pytest.approx(np.linalg.norm(c_mm) / 1000, abs=1e-3)
        assert m.angle_x == pytest.approx(np.arctan2(c_mm[0], c_mm[2]), abs=1e-6)
        # body FRD, relative to the probe tip through the documented default mount
        rel_b = mount.r_bc @ (c_mm / 1000) + np.array(mount.camera_body_m)
        rel_b -= np.array(mount.probe_tip_body_m)
        assert (m.x, m.y, m.z) == pytest.approx(tuple(rel_b), abs=1e-5)
        assert m.x > 0
    assert locked >= 10, "too few locks in 60 ticks of the approach"
    assert heartbeats or stats.heartbeats >= 1
    # while every LED is off: no lock in the telemetry and position_valid 0, no position
    assert dark and hist
    assert not any(h["lock"] for h in hist[-10:])
    assert all(m.position_valid == 0 and m.distance == 0.0 for m in dark)


def test_a_dead_mavlink_heartbeat_turns_healthz_degraded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """healthz lists the MAVLink output: ok while it beats; degraded, naming it, once its
    heartbeat thread has died (here: pymavlink's heartbeat_send raising)."""
    port = _free_udp_port()
    settings = Settings(  # type: ignore[call-arg]
        viser_enabled=False,
        recordings_dir=tmp_path / "rec",
        sim_autostart=False,
        mavlink=f"udpout:127.0.0.1:{port}",
    )
    with TestClient(create_app(settings)) as c:
        h = c.get("/api/v1/healthz").json()
        assert {"name": "mavlink", "status": "ok", "reason": None} in h["components"]

        def broken(*args, **kwargs):  # noqa: ANN002, ANN003
            raise RuntimeError("encoder bug")

        monkeypatch.setattr(mavutil.mavlink.MAVLink, "heartbeat_send", broken)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            h = c.get("/api/v1/healthz").json()
            if h["status"] != "ok":
                break
            time.sleep(0.2)
        comp = next(x for x in h["components"] if x["name"] == "mavlink")
        assert h["status"] == "degraded" and comp["status"] == "degraded"
        assert "heartbeat thread stopped" in comp["reason"]


def test_each_hand_over_is_one_statustext() -> None:
    """The run-time assurance's hand-overs as a pymavlink listener gets them: one STATUSTEXT
    when the recovery law takes over (CRITICAL for an envelope recovery, WARNING for a
    break-away; a long reason in MAVLink 2 chunks), one NOTICE when it hands back or the run
    changes; nothing while the reason stays; LANDING_TARGET goes on for every record."""
    from app.model.tick import TickRecord
    from app.service.mavlink_output import RTA_OFF_TEXT, SIMULATED_TEXT, MavlinkOutput
    from app.service.source_epoch import SourceEpoch

    sev = mavutil.mavlink
    envelope = "envelope: α 10.2° above 10.0° with the probe 1.2 m from the drogue's rim"
    plan = [  # (run, rta_reason)
        (1, None),
        (1, "break-away: missed the drogue by 0.199 m"),
        (1, "break-away: missed the drogue by 0.199 m"),
        (1, None),
        (1, envelope),
        (1, envelope),
        (2, None),  # a new run: the recovery law no longer flies
        (2, None),
    ]
    port = _free_udp_port()
    rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
    sources = SourceEpoch()
    epoch = sources.begin("sim")
    out = MavlinkOutput(
        f"udpout:127.0.0.1:{port}",
        RigMount.on_airframe(default_mount("jsbsim")),
        sources,
        simulated=True,
    )
    try:
        for i, (run, reason) in enumerate(plan):
            rec = TickRecord(
                seq=i,
                source="sim",
                t_s=0.1 * i,
                clock_s=out.clock.now(),
                wall_time=0.0,
                run=run,
                source_epoch=epoch,
            )
            out.on_tick(rec.model_copy(update={"rta_reason": reason}))
        texts = _drain(rx, "STATUSTEXT", 1.5)
        stats = out.stats
    finally:
        out.close()
        rx.close()
    # reassemble the chunks (id ≠ 0: chunk_seq 0, 1, …; id 0: a text of its own)
    got: list[tuple[int, str]] = []
    for m in texts:
        if m.id == 0 or m.chunk_seq == 0:
            got.append((m.severity, m.text))
        else:
            assert got and m.severity == got[-1][0]
            got[-1] = (m.severity, got[-1][1] + m.text)
    assert [m.chunk_seq for m in texts if m.id != 0] == [0, 1]  # the envelope's 86 bytes
    assert got == [
        (sev.MAV_SEVERITY_NOTICE, SIMULATED_TEXT),  # simulated targets begin
        (sev.MAV_SEVERITY_WARNING, "RTA break-away: missed the drogue by 0.199 m"),
        (sev.MAV_SEVERITY_NOTICE, RTA_OFF_TEXT),
        (
            sev.MAV_SEVERITY_CRITICAL,
            "RTA envelope: alpha 10.2 deg above 10.0 deg with the probe 1.2 m from the "
            "drogue's rim",
        ),
        (sev.MAV_SEVERITY_NOTICE, RTA_OFF_TEXT),
    ]
    assert stats.statustexts == 5 and stats.targets == len(plan) and stats.send_errors == 0
