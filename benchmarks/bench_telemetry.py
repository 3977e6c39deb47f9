"""Tick → WebSocket latency (p50/p99) at 30 Hz with 2 telemetry clients, and the tick rate held.

Runs the real service (uvicorn, FastAPI, viser on a free port) in a child process, as deployed,
with the WebSocket clients in this process, for three streams:

* ``baseline``: a trivial step source (no rendering, no vision) — the transport alone;
* ``sim, vision off``: the docking simulation fed the true drogue position (no rendering);
* ``sim``: the docking simulation with vision in the loop (1280×1024 stereo render + pipeline).

Latency = client receive time − the record's ``wall_time`` (stamped when the tick is published;
same machine, same clock). Prints a table with medians and the sim/baseline ratio.

    .venv/bin/python benchmarks/bench_telemetry.py [--seconds 10] [--clients 2] [--hz 30]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.model.pose import PoseResult  # noqa: E402
from app.server.main import create_app  # noqa: E402
from app.service.settings import Settings  # noqa: E402


class TrivialSource:
    """Baseline: publishes a tick without any simulation work."""

    def __init__(self, config, calibration) -> None:
        self.dt = 1.0 / config.tick_hz
        self.k = 0
        self.done = False

    def step(self):
        self.k += 1
        z = np.zeros(3)
        return SimpleNamespace(
            t_s=self.k * self.dt,
            phase="approach",
            drogue_truth_m=z,
            drogue_normal=z,
            drogue_measured_m=z,
            drogue_estimate_m=z,
            probe_tip_m=z,
            uav_state=np.zeros(12),
            reference_m=z,
            control=np.zeros(4),
            lock=True,
            lock_reason=None,
            pose=PoseResult(lock=True),
            left_image=None,
            right_image=None,
            led_truth_cam_mm=None,
            captured=False,
            miss_m=None,
            rel_position_m=z,
            rta_reason=None,
            run_outcome=None,
            hose=None,
            stereo_frame=None,
            image_windows_px=None,
            camera_pose_T=None,
        )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def no_vision(config, calibration):
    """The docking simulation without vision in the loop (built in the worker process)."""
    import dataclasses

    from app.sim.docking import DockingSimulation

    return DockingSimulation(dataclasses.replace(config, vision=False), calibration=calibration)


def serve(mode: str, port: int, hz: float) -> None:
    """Child process: the service with the given stream on ``port`` (uvicorn, one worker)."""
    import uvicorn

    from app.service.sim_worker.proxy import SpawnLauncher, process_source_factory

    sim_factory = {"baseline": TrivialSource, "novision": no_vision, "sim": None}[mode]
    factory = (
        None if sim_factory is None else process_source_factory(launcher=SpawnLauncher(sim_factory))
    )
    settings = Settings(
        port=port,
        viser_port=0,
        tick_hz=hz,
        recordings_dir=Path("/tmp/aar-bench-rec"),
        sim_auto_restart_s=0.5,
    )  # type: ignore[call-arg]
    app = create_app(settings, source_factory=factory)
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning")


async def client(url: str, seconds: float, lat: list[float], seqs: list[int]) -> None:
    import websockets

    async with websockets.connect(url, max_size=None) as ws:
        t_end = time.time() + seconds
        while time.time() < t_end:
            msg = await asyncio.wait_for(ws.recv(), timeout=5)
            now = time.time()
            rec = json.loads(msg)
            lat.append((now - rec["wall_time"]) * 1e3)
            seqs.append(rec["seq"])


def _health(port: int) -> dict:
    import urllib.request

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/healthz", timeout=5) as r:
        return json.loads(r.read())


def _step_ms(port: int) -> float:
    import urllib.request

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/metrics", timeout=5) as r:
        for line in r.read().decode().splitlines():
            # the labels in either order (prometheus_client sorts them)
            if line.startswith("aar_stage_latency_ms{") and all(
                label in line for label in ('stage="step"', 'quantile="0.5"')
            ):
                return float(line.split()[-1])
    return float("nan")


def measure(name: str, mode: str, seconds: float, n_clients: int, hz: float) -> dict:
    """Server in a child process (as deployed); the clients here, in separate processes' shoes."""
    import subprocess

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, __file__, "--serve", mode, "--port", str(port), "--hz", str(hz)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 60
        while True:
            try:
                if _health(port)["ticks"] > 0:
                    break
            except OSError:
                pass
            if time.time() > deadline or proc.poll() is not None:
                raise RuntimeError(f"server ({mode}) did not start")
            time.sleep(0.2)
        time.sleep(1.0)  # warm-up
        h0 = _health(port)
        lats: list[list[float]] = [[] for _ in range(n_clients)]
        seqs: list[list[int]] = [[] for _ in range(n_clients)]
        url = f"ws://127.0.0.1:{port}/api/v1/telemetry"

        async def main() -> None:
            await asyncio.gather(
                *(client(url, seconds, lats[i], seqs[i]) for i in range(n_clients))
            )

        start = time.time()
        asyncio.run(main())
        elapsed = time.time() - start
        h1 = _health(port)
        step_ms = _step_ms(port)
    finally:
        proc.terminate()
        proc.wait(15)
    ticks, dropped = h1["ticks"] - h0["ticks"], h1["dropped_ticks"] - h0["dropped_ticks"]
    all_lat = np.concatenate([np.asarray(x) for x in lats])
    per_client_rate = [len(s) / elapsed for s in seqs]
    return {
        "name": name,
        "p50_ms": float(np.percentile(all_lat, 50)),
        "p99_ms": float(np.percentile(all_lat, 99)),
        "max_ms": float(all_lat.max()),
        "tick_rate_hz": ticks / elapsed,
        "client_rate_hz": float(np.mean(per_client_rate)),
        "dropped": dropped,
        "step_ms": step_ms,
        "n": int(all_lat.size),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--clients", type=int, default=2)
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--serve", choices=("baseline", "novision", "sim"), help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(args.serve, args.port, args.hz)
        return 0
    rows = [
        measure("baseline (no sim work)", "baseline", args.seconds, args.clients, args.hz),
        measure("sim, vision off", "novision", args.seconds, args.clients, args.hz),
        measure("sim (render+vision)", "sim", args.seconds, args.clients, args.hz),
    ]
    print(
        f"\ntick → WebSocket latency, {args.clients} clients, target {args.hz:g} Hz, "
        f"{args.seconds:g} s each\n"
    )
    hdr = (
        f"{'stream':<24}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}{'tick Hz':>9}"
        f"{'client Hz':>11}{'dropped':>9}{'step ms':>9}{'samples':>9}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r['name']:<24}{r['p50_ms']:>9.2f}{r['p99_ms']:>9.2f}{r['max_ms']:>9.1f}"
            f"{r['tick_rate_hz']:>9.1f}{r['client_rate_hz']:>11.1f}{r['dropped']:>9d}"
            f"{r['step_ms']:>9.1f}{r['n']:>9d}"
        )
    b, s = rows[0], rows[-1]
    print(
        f"\nratio sim/baseline: p50 latency ×{s['p50_ms'] / b['p50_ms']:.2f}, "
        f"p99 ×{s['p99_ms'] / b['p99_ms']:.2f}, tick rate ×{s['tick_rate_hz'] / b['tick_rate_hz']:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
