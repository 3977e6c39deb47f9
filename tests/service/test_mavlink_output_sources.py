"""Only the configured source on MAVLink (issue 31, item 6), seen as an autopilot sees it: a
real ``python -m app serve`` process with ``--mavlink udpout:…`` and a ``pymavlink`` listener on
UDP loopback opened *before* the process starts, so that nothing it sends is missed.

- ``--source video:…``: no ``LANDING_TARGET`` whose distance lies outside the video's true
  range (the simulated stream's 13 m fixes must never go out);
- a pushed stream with a forced no-lock (dark pairs): ``position_valid`` 0 and no position on
  those pairs, only the pushed pairs' fixes, and the last fix withdrawn once stale;
- switching the source (``PUT /api/v1/stream/source``): nothing of the old source after the
  switch returns (a marker datagram sent by the test after the reply splits the received
  stream: loopback delivers one socket's datagrams in the order they were sent), and nothing
  of the simulation, whose targets go out only with ``--mavlink-sim``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest

from app.resources import load_default_calibration
from app.streams.mavlink_link import MavlinkLink  # noqa: F401  (MAVLink 2 dialect first)
from app.streams.protocol import encode_message
from tests.support.live_server import free_port
from tests.support.streams_sequence import (
    FPS,
    Sequence,
    cached_sequence,
    render_sequence,
    write_avi,
)
from tests.support.waiting import stop_process, wait_for_server, wait_until

ROOT = Path(__file__).resolve().parents[2]
N = 40
MAX_AGE_S = 0.25  # the service's default Settings.mavlink_max_age_s
MARK = b"MARK"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _true_range_m(seq: Sequence) -> tuple[float, float]:
    r = [float(np.linalg.norm(c)) / 1000.0 for c in seq.centers_mm]
    return min(r), max(r)


@dataclass
class Listener:
    """Every LANDING_TARGET and STATUSTEXT received, in order, with the receipt time."""

    port: int
    got: list[tuple[float, Any]] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        from pymavlink import mavutil

        rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", dialect="common")
        self.ready.set()
        try:
            while not self.stop.is_set():
                m = rx.recv_match(type=["LANDING_TARGET", "STATUSTEXT"], blocking=True, timeout=0.1)
                if m is not None:
                    self.got.append((time.monotonic(), m))
        finally:
            rx.close()

    def __post_init__(self) -> None:
        self.ready = threading.Event()

    def targets(self) -> list[Any]:
        return [m for _, m in list(self.got) if m.get_type() == "LANDING_TARGET"]

    def mark(self, n: int) -> None:
        """A STATUSTEXT from another system into the same socket, after all sent so far."""
        from pymavlink import mavutil

        tx = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.port}", source_system=99)
        tx.mav.statustext_send(6, MARK + str(n).encode(), 0, 0)
        tx.close()

    def split(self) -> list[list[Any]]:
        """The targets between the markers: [before 1, between 1 and 2, …]."""
        parts: list[list[Any]] = [[]]
        for _, m in list(self.got):
            if m.get_type() == "STATUSTEXT" and m.get_srcSystem() == 99:
                parts.append([])
            elif m.get_type() == "LANDING_TARGET":
                parts[-1].append(m)
        return parts


@contextmanager
def serve_with_listener(tmp_path: Path, *args: str) -> Iterator[tuple[Listener, int]]:
    """The listener up first, then ``python -m app serve --mavlink udpout:…`` (defaults: the
    simulation in its worker process, as deployed), until the service answers."""
    listener = Listener(_free_udp_port())
    thread = threading.Thread(target=listener.run, daemon=True)
    thread.start()
    assert listener.ready.wait(10)
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_RECORDINGS_DIR=str(tmp_path / "rec"))  # as deployed: upload workers too
    env.update(AAR_STREAM_ROOTS=str(tmp_path), PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "app", "serve", "--no-viser", "--port", str(port)]
    cmd += ["--mavlink", f"udpout:127.0.0.1:{listener.port}", *args]
    log_path = tmp_path / f"serve-{port}.log"
    with log_path.open("wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
        try:
            wait_for_server(
                proc,
                lambda: httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=1).is_success,
                log_path,
                timeout_s=180.0,
            )
            yield listener, port
        finally:
            stop_process(proc)
            listener.stop.set()
            thread.join(5)


@pytest.fixture(scope="module")
def near(tmp_path_factory: pytest.TempPathFactory) -> tuple[Sequence, Path, Path]:
    """The drogue closing from 1.30 to 0.73 m, as MJPG videos."""
    d = tmp_path_factory.mktemp("near")
    seq = cached_sequence(N)
    left, right = write_avi(seq, d)
    return seq, left, right


def test_video_source_sends_only_the_videos_fixes(
    tmp_path: Path, near: tuple[Sequence, Path, Path]
) -> None:
    """``serve --source video:L,R``: from the first message on, only the video's fixes (its
    true range), none marked simulated; at its end the last fix is withdrawn once stale."""
    seq, left, right = near
    lo, hi = _true_range_m(seq)
    with serve_with_listener(tmp_path, "--source", f"video:{left},{right}") as (rx, port):
        base = f"http://127.0.0.1:{port}/api/v1"
        wait_until(
            lambda: httpx.get(f"{base}/stream", timeout=5).json()["state"] == "ended", 60, "end"
        )
        time.sleep(MAX_AGE_S + 0.5)
    got = rx.targets()
    valid = [m for m in got if m.position_valid]
    assert len(valid) >= 0.8 * N
    outside = [round(m.distance, 3) for m in valid if not lo - 0.02 <= m.distance <= hi + 0.02]
    assert not outside, f"fixes outside the video's {lo:.2f}–{hi:.2f} m: {outside[:10]}"
    assert all(m.target_num == 0 for m in got)  # real targets: never marked simulated
    # the video ended: its last fix is not left standing as valid
    assert got[-1].position_valid == 0 and got[-1].time_usec > valid[-1].time_usec


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()


def test_forced_no_lock_and_a_stalled_push_are_not_valid(tmp_path: Path) -> None:
    """Pushed pairs: 10 locked, 10 dark (every LED off: no lock), 10 locked, then the pusher
    stops. Dark pairs go out with position_valid 0 and no position; every valid fix is one of
    the pushed locked pairs'; the last one is withdrawn within the max age."""
    from websockets.sync.client import connect

    seq = cached_sequence(N)
    dark = _png(np.zeros_like(seq.lefts[0]))
    plan = [(i, True) for i in range(10)] + [(i, False) for i in range(10, 20)]
    plan += [(i, True) for i in range(20, 30)]
    times = {i: i / FPS for i, _ in plan}
    with serve_with_listener(tmp_path, "--source", "push") as (rx, port):
        with connect(f"ws://127.0.0.1:{port}/api/v1/stream/push", max_size=None) as ws:
            for i, lit in plan:
                left, right = (_png(seq.lefts[i]), _png(seq.rights[i])) if lit else (dark, dark)
                ws.send(encode_message(left, right, t_s=times[i], seq=i))
                time.sleep(1.0 / FPS)
        wait_until(lambda: any(m.time_usec > 29e6 / FPS for m in rx.targets()), 30, "last pair")
        time.sleep(MAX_AGE_S + 1.0)
    got = rx.targets()
    by_usec = {round(times[i] * 1e6): lit for i, lit in plan}
    on_pairs = [m for m in got if m.time_usec in by_usec]
    dark_got = [m for m in on_pairs if not by_usec[m.time_usec]]
    assert len(dark_got) >= 3 and sum(m.position_valid for m in on_pairs) >= 10
    assert all(m.position_valid == 0 and m.distance == 0.0 for m in dark_got)
    # every valid fix is a pushed locked pair's (nothing of the simulation)
    assert all(by_usec.get(m.time_usec) for m in got if m.position_valid), [
        (m.time_usec, round(m.distance, 2)) for m in got if m.time_usec not in by_usec
    ][:10]
    # the stalled pusher: its last fix is withdrawn (position_valid 0, a later time) in time
    last = max(i for i, m in enumerate(got) if m.position_valid)
    after = got[last + 1 :]
    assert after and after[0].position_valid == 0 and after[0].time_usec > got[last].time_usec
    t_valid = next(t for t, m in rx.got if m is got[last])
    t_withdrawn = next(t for t, m in rx.got if m is after[0])
    assert t_withdrawn - t_valid <= MAX_AGE_S + 0.2
    assert all(m.position_valid == 0 for m in after)


def test_nothing_of_the_old_source_after_a_switch(
    tmp_path: Path, near: tuple[Sequence, Path, Path]
) -> None:
    """video A (0.73–1.30 m) → video B (2.0–2.3 m) → the simulation (not asked for on
    MAVLink): after each switch returns, no fix of the source before it."""
    seq_a, la, ra = near
    seq_b = render_sequence(load_default_calibration(), 20, depth_mm=2000.0)
    (tmp_path / "far").mkdir()
    lb, rb = write_avi(seq_b, tmp_path / "far")
    range_a, range_b = _true_range_m(seq_a), _true_range_m(seq_b)

    def valid_in(part: int, rng: tuple[float, float]) -> int:
        parts = rx.split()
        if len(parts) <= part:
            return 0
        return sum(
            m.position_valid and rng[0] - 0.02 <= m.distance <= rng[1] + 0.02 for m in parts[part]
        )

    with serve_with_listener(tmp_path, "--source", f"video:{la},{ra}", "--loop") as (rx, port):
        base = f"http://127.0.0.1:{port}/api/v1"
        wait_until(lambda: valid_in(0, range_a) >= 10, 120, "fixes of video A")
        r = httpx.put(
            f"{base}/stream/source", json={"source": f"video:{lb},{rb}", "loop": True}, timeout=60
        )
        assert r.status_code == 200, r.text
        rx.mark(1)
        wait_until(lambda: valid_in(1, range_b) >= 10, 60, "fixes of video B")
        r = httpx.put(f"{base}/stream/source", json={"source": "sim"}, timeout=60)
        assert r.status_code == 200, r.text
        rx.mark(2)
        time.sleep(2.0)
        sim_ticks = httpx.get(f"{base}/history", params={"seconds": 1.0}, timeout=10).json()
    before, between, after = rx.split()
    assert any(t["source"] == "sim" for t in sim_ticks)  # the simulation did run

    def which(m: Any) -> str:
        for name, (lo, hi) in (("A", range_a), ("B", range_b)):
            if lo - 0.02 <= m.distance <= hi + 0.02:
                return name
        return f"{m.distance:.2f} m"

    # video A's fixes, then B's (B's first ones may precede the marker: B started before the
    # reply), never A's after the switch returned nor after B's first, and never another's
    order = [which(m) for m in before + between if m.position_valid]
    assert set(order) == {"A", "B"}, sorted(set(order))
    assert "A" not in order[order.index("B") :]
    assert all(which(m) == "B" for m in between if m.position_valid)
    assert not any(m.position_valid for m in after), [round(m.distance, 2) for m in after][:10]
    assert all(m.target_num == 0 for m in before + between + after)
    # B's last fix was withdrawn (position_valid 0 is the last word)
    assert (between + after)[-1].position_valid == 0
