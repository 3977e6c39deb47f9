"""One pair, one answer (issue 31 items 4–5, acceptance "Parity" and "Profile").

The same rendered pairs — colour and mono, the paper's 75 mm ring and a 305 mm basket — go
through ``aar-dock process``, ``POST /api/v1/stereo`` (its one path, ``process_upload``,
called directly and through the route with a thread executor in the web process), a pushed pair on ``/api/v1/stream/push`` and ``aar-dock track``; each
entry point is told the drogue by the same profile file. The answers must agree: the same
lock and reason, the centre within 0.01 mm. Then the profile: a 305 mm drogue is locked by
``--ring-radius-mm 305`` (the service with ``AAR_RING_RADIUS_MM`` and no simulation, and
``track``), and never by the 75 mm profile.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.cli.main import main as cli_main
from app.resources import load_default_calibration
from app.service.sim_worker.wire import calibration_to_wire
from app.service.upload_pool import process_upload
from app.sim.led_ring import LedRing
from app.sim.stereo_render import RenderSettings, render_pair
from app.streams.protocol import encode_message
from app.vision.drogue import BASKET_24IN, PAPER_DROGUE, DrogueProfile
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.stream_checks import history_records
from tests.support.upload_executor import thread_uploads
from tests.support.waiting import wait_until

CENTRE_TOL_MM = 0.01
# (drogue, ring centres in the left camera frame, mm): the paper's ring at 0.9–1.3 m, the
# basket (20 mm LEDs) at 4–6 m
CASES: dict[str, tuple[DrogueProfile, list[tuple[float, float, float]]]] = {
    "75mm": (PAPER_DROGUE, [(15.0, -10.0, 1100.0), (-40.0, 25.0, 900.0), (30.0, 5.0, 1300.0)]),
    "305mm": (BASKET_24IN, [(40.0, -30.0, 5000.0), (-120.0, 60.0, 4000.0), (90.0, 20.0, 6000.0)]),
}


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()


def _render(drogue: DrogueProfile, centre: tuple[float, float, float], colour: bool, seed: int):
    ring = LedRing(drogue.ring_radius_mm, drogue.led_count, drogue.led_diameter_mm)
    normal = np.array([0.08, -0.05, -1.0])
    pair = render_pair(
        load_default_calibration(),
        np.array(centre),
        normal,
        RenderSettings(color=colour),
        ring,
        seed,
    )
    return pair.left, pair.right


def _summary(res: dict[str, Any]) -> tuple[bool, str | None, list[float] | None]:
    centre = res["drogue"]["center_mm"] if res["lock"] and res["drogue"] else None
    return bool(res["lock"]), res["reason"], centre


def _assert_same(name: str, ref: dict[str, Any], other: dict[str, Any]) -> None:
    (lock_a, why_a, c_a), (lock_b, why_b, c_b) = _summary(ref), _summary(other)
    assert lock_a == lock_b, f"{name}: {why_a!r} vs {why_b!r}"
    if not lock_a:  # a stream's lock says how it got it ("acquired: full frame")
        assert why_a == why_b, name
    if c_a is not None:
        d = float(np.max(np.abs(np.subtract(c_a, c_b))))
        assert d <= CENTRE_TOL_MM, f"{name}: centres differ by {d:.4f} mm"


@pytest.mark.parametrize("case", sorted(CASES))
def test_process_upload_push_and_track_give_one_answer(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drogue, centres = CASES[case]
    profile = tmp_path / "drogue.json"
    drogue.save(profile)
    calib = load_default_calibration()
    pairs = []  # (name, left path, right path, left bytes, right bytes)
    for k, centre in enumerate(centres):
        for colour in (False, True):
            left, right = _render(drogue, centre, colour, seed=10 + k)
            assert (left.ndim == 3) == colour
            name = f"{case}-{k}-{'colour' if colour else 'mono'}"
            lp, rp = tmp_path / f"{name}-L.png", tmp_path / f"{name}-R.png"
            lp.write_bytes(_png(left))
            rp.write_bytes(_png(right))
            pairs.append((name, lp, rp))
    # aar-dock process
    answers: dict[str, dict[str, Any]] = {}
    for name, lp, rp in pairs:
        capsys.readouterr()
        assert cli_main(["process", str(lp), str(rp), "--json", "--drogue", str(profile)]) == 0
        answers[name] = json.loads(capsys.readouterr().out)
    assert sum(a["lock"] for a in answers.values()) >= len(pairs) - 1, "renders should lock"
    assert any(a["lock"] for n, a in answers.items() if "colour" in n)
    # an upload worker's function, as the pool runs it
    for name, lp, rp in pairs:
        out = process_upload(
            lp.read_bytes(),
            rp.read_bytes(),
            calibration_to_wire(calib),
            "epipolar",
            calib.image_size,
            drogue.to_dict(),
        )
        assert out.status == 200 and out.result is not None, out
        _assert_same(f"{name} upload worker", answers[name], out.result.model_dump(mode="python"))
    # the service (AAR_DROGUE): POST /stereo, then each pair pushed to a fresh push stream
    settings = service_settings(tmp_path, **SIM_IDLE, drogue=profile, history_s=600.0)
    with TestClient(service_app(settings, upload_executor=thread_uploads)) as c:
        assert c.get("/api/v1/healthz").json()["configured_drogue"]["ring_radius_mm"] == (
            drogue.ring_radius_mm
        )
        for name, lp, rp in pairs:
            files = {"left": ("l.png", lp.read_bytes()), "right": ("r.png", rp.read_bytes())}
            r = c.post("/api/v1/stereo", files=files)
            assert r.status_code == 200, r.text
            _assert_same(f"{name} POST /stereo", answers[name], r.json())
        for i, (name, lp, rp) in enumerate(pairs):
            assert c.put("/api/v1/stream/source", json={"source": "push"}).status_code == 200
            with c.websocket_connect("/api/v1/stream/push") as ws:
                ws.send_bytes(encode_message(lp.read_bytes(), rp.read_bytes(), t_s=0.0, seq=i))
                wait_until(lambda: c.get("/api/v1/stream").json()["frames"] >= 1, 30, name)
            rec = [r for r in history_records(c, "push") if r["stream"]["frame"] == i][-1]
            _assert_same(f"{name} push", answers[name], rec["pose"])
            assert c.put("/api/v1/stream/source", json={"source": "sim"}).status_code == 200
    # aar-dock track over one-pair image folders
    for name, lp, rp in pairs:
        dl, dr = tmp_path / f"{name}-l", tmp_path / f"{name}-r"
        dl.mkdir()
        dr.mkdir()
        (dl / "000000.png").write_bytes(lp.read_bytes())
        (dr / "000000.png").write_bytes(rp.read_bytes())
        out = tmp_path / f"{name}.jsonl"
        argv = ["track", "--left", str(dl), "--right", str(dr), "--drogue", str(profile)]
        assert cli_main([*argv, "--jsonl", str(out), "--no-progress"]) == 0
        (row,) = [json.loads(x) for x in out.open()]
        _assert_same(f"{name} track", answers[name], row)


def test_ring_radius_shortcut_locks_a_305mm_drogue_and_the_75mm_profile_never_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--ring-radius-mm 305`` keeps the profile's 5 mm LEDs: a 305 mm ring of such LEDs."""
    drogue = PAPER_DROGUE.with_radius(305.0)
    centres = [(40.0, -30.0, 1500.0), (-60.0, 40.0, 2000.0), (20.0, 10.0, 2500.0)]
    pairs = []
    for k, centre in enumerate(centres):
        for colour in (False, True):
            left, right = _render(drogue, centre, colour, seed=30 + k)
            pairs.append((_png(left), _png(right), left, right))
    # the service: AAR_RING_RADIUS_MM=305, no simulation
    settings = service_settings(tmp_path, **SIM_IDLE, ring_radius_mm=305.0)
    settings_75 = service_settings(tmp_path, **SIM_IDLE)
    for s, want in ((settings, True), (settings_75, False)):
        with TestClient(service_app(s, upload_executor=thread_uploads)) as c:
            assert c.get("/api/v1/healthz").json()["configured_drogue"]["ring_radius_mm"] == (
                305.0 if want else 75.0
            )
            for lb, rb, _, _ in pairs:
                r = c.post("/api/v1/stereo", files={"left": ("l.png", lb), "right": ("r.png", rb)})
                assert r.status_code == 200 and r.json()["lock"] is want, r.json()["reason"]
    # aar-dock track --ring-radius-mm 305 (and without it: the paper's 75 mm ring)
    dl, dr = tmp_path / "l", tmp_path / "r"
    dl.mkdir()
    dr.mkdir()
    for i, (lb, rb, _, _) in enumerate(pairs):
        (dl / f"{i:06d}.png").write_bytes(lb)
        (dr / f"{i:06d}.png").write_bytes(rb)
    for extra, want in ((["--ring-radius-mm", "305"], True), ([], False)):
        out = tmp_path / f"track{len(extra)}.jsonl"
        argv = ["track", "--left", str(dl), "--right", str(dr), "--jsonl", str(out), *extra]
        assert cli_main([*argv, "--no-progress", "--fps", "1"]) == 0
        rows = [json.loads(x) for x in out.open()]
        assert len(rows) == len(pairs) and all(r["lock"] is want for r in rows), [
            r["reason"] for r in rows
        ]
