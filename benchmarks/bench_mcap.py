"""Recording to MCAP at 30 Hz: the tick rate the service keeps, and the MCAP's size per minute.

Runs the real service (``aar-dock serve``: the docking simulation with vision in the loop, its
stereo pair rendered every camera frame) in a child process and measures its tick rate
(``/healthz`` tick counts over a window) alternately without a recording (the baseline) and
while recording with frames (``POST /recording/start?frames=true``: JSONL + PNG frames +
``<id>.mcap``). Prints the rates, their ratio (recording / baseline), the pairs recorded and
dropped, and the MCAP's MB per minute of recording.

    .venv/bin/python benchmarks/bench_mcap.py [--seconds 20] [--hz 30] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def api(port: int, path: str, method: str = "GET") -> Any:
    req = urllib.request.Request(f"http://127.0.0.1:{port}/api/v1/{path}", method=method)
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


ROOT = Path(__file__).resolve().parents[1]


def aar_dock() -> list[str]:
    """This checkout's ``aar-dock`` (``python -m app`` in the repository root)."""
    return [sys.executable, "-m", "app"]


def rate(port: int, seconds: float) -> tuple[float, int]:
    """Ticks per second over ``seconds`` and the deadlines dropped meanwhile."""
    h0 = api(port, "healthz")
    t0 = time.monotonic()
    time.sleep(seconds)
    h1 = api(port, "healthz")
    dt = time.monotonic() - t0
    return (h1["ticks"] - h0["ticks"]) / dt, int(h1["dropped_ticks"] - h0["dropped_ticks"])


def record(port: int, seconds: float, frames: bool) -> tuple[dict[str, Any], float, int]:
    """A recording over one window: its final metadata, the tick rate and drops meanwhile."""
    info = api(port, f"recording/start?frames={'true' if frames else 'false'}", "POST")
    hz, dropped = rate(port, seconds)
    api(port, "recording/stop", "POST")
    while True:
        meta: dict[str, Any] = api(port, f"recordings/{info['id']}")
        if not meta["active"] and meta["status"] != "recording":
            return meta, hz, dropped
        time.sleep(0.2)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="each measured window (s)")
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--rounds", type=int, default=2, help="baseline/recording pairs")
    ap.add_argument("--warmup", type=float, default=20.0, help="s before the first window")
    args = ap.parse_args()
    rec_dir = Path(tempfile.mkdtemp(prefix="bench_mcap_"))
    port = free_port()
    env = dict(os.environ)
    env.update(
        {
            "AAR_TICK_HZ": str(args.hz),
            "AAR_SIM_AUTO_RESTART_S": "0",
            "AAR_RECORDINGS_DIR": str(rec_dir),
            "AAR_LOG_LEVEL": "warning",
        }
    )
    env.pop("AAR_TOKEN", None)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [*aar_dock(), "serve", "--port", str(port), "--viser-port", str(free_port())]
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    rows: list[dict[str, Any]] = []
    try:
        deadline = time.time() + 180
        while True:
            try:
                if api(port, "healthz")["ticks"] > 0:
                    break
            except OSError:
                pass
            if proc.poll() is not None or time.time() > deadline:
                log.seek(0)
                print(log.read().decode(errors="replace")[-2000:], file=sys.stderr)
                return 1
            time.sleep(0.5)
        time.sleep(args.warmup)
        for _ in range(args.rounds):
            base, base_drop = rate(port, args.seconds)
            meta, rec, rec_drop = record(port, args.seconds, frames=True)
            minutes = (meta["stopped_wall"] - meta["started_wall"]) / 60.0
            plain, _, _ = record(port, args.seconds, frames=False)
            plain_min = (plain["stopped_wall"] - plain["started_wall"]) / 60.0
            rows.append(
                {
                    "baseline_hz": base,
                    "baseline_dropped": base_drop,
                    "recording_hz": rec,
                    "recording_dropped": rec_drop,
                    "ratio": rec / base if base else float("nan"),
                    "ticks": meta["ticks"],
                    "pairs": meta["frame_pairs"],
                    "pairs_dropped": meta["frames_dropped"],
                    "mcap_mb_per_min": meta["mcap_bytes"] / 1e6 / minutes,
                    "frames_mb_per_min": meta["frames_bytes"] / 1e6 / minutes,
                    "mcap_note": meta.get("mcap_note"),
                    "telemetry_only_mcap_mb_per_min": plain["mcap_bytes"] / 1e6 / plain_min,
                    "jsonl_mb_per_min": plain["telemetry_bytes"] / 1e6 / plain_min,
                }
            )
            print(json.dumps(rows[-1]), flush=True)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(rec_dir, ignore_errors=True)
    print(f"\nnominal {args.hz:g} Hz, {args.seconds:g} s windows, {len(rows)} rounds")
    print(
        "round  baseline Hz  recording Hz  ratio   pairs (dropped)  MCAP MB/min"
        "  (frames folder)  no frames: MCAP / JSONL MB/min"
    )
    for i, r in enumerate(rows):
        print(
            f"{i:5d}  {r['baseline_hz']:11.2f}  {r['recording_hz']:12.2f}  {r['ratio']:5.3f}"
            f"  {r['pairs']:6d} ({r['pairs_dropped']:3d})  {r['mcap_mb_per_min']:11.1f}"
            f"  ({r['frames_mb_per_min']:.1f})  {r['telemetry_only_mcap_mb_per_min']:.2f}"
            f" / {r['jsonl_mb_per_min']:.2f}"
        )
    ratios = sorted(r["ratio"] for r in rows)
    print(f"median ratio {ratios[len(ratios) // 2]:.3f} (target ≥ 0.99)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
