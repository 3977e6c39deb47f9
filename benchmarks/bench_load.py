"""Tick rate of the live service under load: telemetry clients and uploaders.

Starts ``aar-dock serve`` (vision on, 30 Hz, viser on, free ports) in a child process, as
deployed, and measures the tick rate over a window (``/healthz`` ticks and dropped deadlines)
and, from ``/history``, the p99 of the step latency (from a tick's deadline to its result
being available: in process mode the worker's deadline to the worker releasing the tick), of
the relay (the worker's deadline to the record being ready to publish in the web server's
process) and of the worker's compute time per tick, in these cases:

* ``idle``: no clients;
* ``ws50``: 50 telemetry WebSocket clients (receiving, not parsing);
* ``up16``: 16 uploaders posting ``sample_data/pair_1000mm/{left,right}.png`` in a loop, as
  fast as answered (429 when ``AAR_MAX_CONCURRENT_UPLOADS`` are running: counted, no back-off);
* ``both``: the two together;
* ``page``: one browser (Debian chromium, headless, software WebGL) on the operators' page,
  which embeds the viser 3-D scene;
* ``full``: the page + 50 telemetry clients + 4 uploaders (issue 10's acceptance load); these
  uploaders honour the 429's ``Retry-After`` (in ``up16``/``both`` they retry at once: stress).

in the service's one mode, ``process`` (the simulation in a worker process, uploads in a
process pool; the old ``thread`` mode, the simulation in a thread of the web server, is gone:
the simulation has one execution path, and its figures in ``docs/service.md`` are history).

The clients run in this process (asyncio: ``websockets``, ``httpx``). Each mode runs with
AAR_MAX_CONCURRENT_UPLOADS = 2 (the default: at most 2 uploads processed at once, the others
429) and 16 (every uploader admitted). Prints a Markdown table: with ``--repeat N`` the
medians of N runs (the ``idle`` case of the same runs is the baseline); ``--detail`` prints
every timing's p50/p99/max per case.

    .venv/bin/python benchmarks/bench_load.py [--seconds 10] [--hz 30] [--modes process]
    flock /tmp/aar_bench.lock .venv/bin/python benchmarks/bench_load.py --modes process \
        --max-uploads 2 --cases idle,ws50,page,full --repeat 3
"""

from __future__ import annotations

import argparse
import asyncio
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
from collections import Counter
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
PAIR = REPO / "sample_data" / "pair_1000mm"
CASES = ("idle", "ws50", "up16", "both", "page", "full")
N_WS = 50
N_UP = {"up16": 16, "both": 16, "full": 4}
CHROMIUM = "/usr/bin/chromium"
MODE_ENV: dict[str, dict[str, str]] = {"process": {}}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(port: int, path: str) -> bytes:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/{path}", timeout=10) as r:
        data: bytes = r.read()
        return data


def health(port: int) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(_get(port, "healthz"))
    return out


def window_p99(port: int, seconds: float, detail: bool = False) -> dict[str, float]:
    """p99 over the last ``seconds`` (``/history``) of the sim ticks' timings: ``step`` (from
    the tick's deadline to its result being available), ``relay`` (from the deadline to the
    record being ready to publish in the web server's process; process mode) and ``sim`` (the
    worker process's own step time). ``detail``: print p50/p99/max of every timing."""
    import numpy as np

    records = json.loads(_get(port, f"history?seconds={seconds:.3f}"))
    sims = [r["timings_ms"] for r in records if r["source"] == "sim"]
    out: dict[str, float] = {}
    for stage in sorted({k for t in sims for k in t} | {"step", "relay", "sim"}):
        vals = [t[stage] for t in sims if stage in t]
        out[stage] = float(np.percentile(vals, 99)) if vals else float("nan")
        if detail and vals:
            print(
                f"    {stage:12s} p50 {np.percentile(vals, 50):7.2f}  p99 {out[stage]:7.2f}"
                f"  max {max(vals):7.2f} ms  (n={len(vals)})"
            )
    return out


def aar_dock() -> list[str]:
    exe = Path(sys.executable).parent / "aar-dock"
    if exe.exists():
        return [str(exe)]
    found = shutil.which("aar-dock")
    return [found] if found else [sys.executable, "-m", "app"]


class Server:
    """``aar-dock serve`` in a child process."""

    def __init__(self, mode: str, hz: float, rec_dir: Path, max_uploads: int) -> None:
        self.mode = mode
        self.max_uploads = max_uploads
        self.port = free_port()
        viser_port = free_port()
        env = dict(os.environ)
        env.update(MODE_ENV[mode])
        env.update(
            {
                "AAR_TICK_HZ": str(hz),
                "AAR_SIM_AUTO_RESTART_S": "0",  # a finished run restarts at once
                "AAR_RECORDINGS_DIR": str(rec_dir),
                "AAR_LOG_LEVEL": "warning",
            }
        )
        env["AAR_MAX_CONCURRENT_UPLOADS"] = str(max_uploads)
        env.pop("AAR_TOKEN", None)
        cmd = [*aar_dock(), "serve", "--port", str(self.port), "--viser-port", str(viser_port)]
        self.log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT)

    def wait_ticking(self, timeout_s: float = 90.0) -> None:
        deadline = time.time() + timeout_s
        while True:
            try:
                if health(self.port)["ticks"] > 0:
                    return
            except OSError:
                pass
            if self.proc.poll() is not None or time.time() > deadline:
                self.log.seek(0)
                tail = self.log.read().decode(errors="replace")[-2000:]
                raise RuntimeError(f"server ({self.mode}) did not start:\n{tail}")
            time.sleep(0.2)

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGTERM)  # graceful: the lifespan stops the workers
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self.log.seek(0)
        return self.log.read().decode(errors="replace")


async def ws_client(url: str, stop: asyncio.Event, counts: list[int], i: int) -> None:
    import websockets

    async with websockets.connect(url, max_size=None) as ws:
        while not stop.is_set():
            try:
                await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            counts[i] += 1


async def uploader(
    url: str, stop: asyncio.Event, statuses: Counter[int], files: Any, polite: bool = False
) -> None:
    """Post the pair in a loop, as fast as answered; ``polite``: wait the 429's Retry-After
    before the next post (a well-behaved client) instead of retrying at once."""
    import httpx

    async with httpx.AsyncClient(timeout=30.0) as client:
        while not stop.is_set():
            try:
                r = await client.post(url, files=files)
                statuses[r.status_code] += 1
                if polite and r.status_code == 429:
                    await asyncio.sleep(float(r.headers.get("retry-after", "1")))
            except httpx.HTTPError:
                statuses[-1] += 1  # connection closed early (a refused body), counted apart


async def open_page(port: int) -> tuple[Any, Any, Any]:
    """Debian chromium (headless, software WebGL) on the operators' page (3-D view embedded)."""
    from playwright.async_api import async_playwright

    pw = await async_playwright().start()
    br = await pw.chromium.launch(
        executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu"]
    )
    page = await br.new_page(viewport={"width": 1400, "height": 900})
    await page.goto(f"http://127.0.0.1:{port}/", wait_until="load")
    return pw, br, page


async def run_case(
    server: Server, case: str, seconds: float, ramp_s: float, detail: bool = False
) -> dict[str, Any]:
    port = server.port
    stop = asyncio.Event()
    ws_counts = [0] * N_WS
    statuses: Counter[int] = Counter()
    files = {
        "left": ("left.png", (PAIR / "left.png").read_bytes(), "image/png"),
        "right": ("right.png", (PAIR / "right.png").read_bytes(), "image/png"),
    }
    tasks: list[asyncio.Task[None]] = []
    if case in ("ws50", "both", "full"):
        url = f"ws://127.0.0.1:{port}/api/v1/telemetry"
        tasks += [asyncio.create_task(ws_client(url, stop, ws_counts, i)) for i in range(N_WS)]
    if case in N_UP:
        url = f"http://127.0.0.1:{port}/api/v1/stereo"
        polite = case == "full"
        tasks += [
            asyncio.create_task(uploader(url, stop, statuses, files, polite))
            for _ in range(N_UP[case])
        ]
    browser = None
    if case in ("page", "full"):
        browser = await open_page(port)
        ramp_s = max(ramp_s, 6.0)  # the page and its 3-D view load and start rendering
    await asyncio.sleep(ramp_s)
    h0 = await asyncio.to_thread(health, port)
    t0 = time.monotonic()
    ws0, st0 = sum(ws_counts), Counter(statuses)
    await asyncio.sleep(seconds)
    h1 = await asyncio.to_thread(health, port)
    elapsed = time.monotonic() - t0
    ws1, st1 = sum(ws_counts), Counter(statuses)
    p99 = await asyncio.to_thread(window_p99, port, elapsed, detail)
    page_ok = None
    if browser is not None:
        pw, br, page = browser
        page_ok = await page.evaluate(
            "() => document.querySelector('#viser-frame') !== null"
            " && (document.querySelector('#t_s')?.textContent ?? '–') !== '–'"
        )
        await br.close()
        await pw.stop()
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    answered = st1 - st0
    return {
        "slots": server.max_uploads,
        "case": case,
        "mode": server.mode,
        "tick_hz": (h1["ticks"] - h0["ticks"]) / elapsed,
        "dropped": h1["dropped_ticks"] - h0["dropped_ticks"],
        "errors": h1["errors"] - h0["errors"],
        "step_p99": p99["step"],
        "relay_p99": p99["relay"],
        "sim_p99": p99["sim"],
        "ok_per_s": answered.get(200, 0) / elapsed,
        "busy_per_s": answered.get(429, 0) / elapsed,
        "closed_per_s": answered.get(-1, 0) / elapsed,
        "other": {k: v for k, v in answered.items() if k not in (200, 429, -1)},
        "ws_per_client_hz": (
            (ws1 - ws0) / elapsed / N_WS if case in ("ws50", "both", "full") else None
        ),
        "page_live": page_ok,
    }


def measure_mode(
    mode: str,
    hz: float,
    seconds: float,
    ramp_s: float,
    max_uploads: int,
    cases: list[str],
    detail: bool = False,
) -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory(prefix="aar-bench-load-") as rec:
        server = Server(mode, hz, Path(rec), max_uploads)
        rows: list[dict[str, Any]] = []
        try:
            server.wait_ticking()
            time.sleep(4.0)  # warm-up (workers started, first runs built)
            for case in cases:
                row = asyncio.run(run_case(server, case, seconds, ramp_s, detail))
                rows.append(row)
                print(
                    f"  slots {max_uploads:<3} {mode:<8}{case:<6} {row['tick_hz']:6.2f} Hz"
                    f"  dropped {row['dropped']:4d}  errors {row['errors']}"
                    f"  step p99 {row['step_p99']:6.1f} ms  relay p99 {row['relay_p99']:6.1f} ms"
                    f"  sim p99 {row['sim_p99']:6.1f} ms"
                    f"  uploads/s: {row['ok_per_s']:.1f} ok, {row['busy_per_s']:.1f} 429,"
                    f" {row['closed_per_s']:.1f} closed {row['other'] or ''}",
                    flush=True,
                )
                time.sleep(1.0)
        finally:
            log = server.stop()
        errors = [ln for ln in log.splitlines() if "Traceback" in ln or "ERROR" in ln]
        if errors:
            print(f"  ({mode}: {len(errors)} error lines in the server log)", flush=True)
            print(log[-3000:], flush=True)
    return rows


def _median(rows: list[dict[str, Any]], key: str) -> float:
    import numpy as np

    vals = [float(r[key]) for r in rows if r[key] is not None]
    return float(np.median(vals)) if vals else float("nan")


def _ms(v: float) -> str:
    return "–" if v != v else f"{v:.1f}"


def table(rows: list[dict[str, Any]], hz: float) -> str:
    """Medians over the repeated runs of each (slots, case, mode)."""
    head = (
        "| upload slots | case | mode | runs | tick rate (Hz) | ratio to nominal | dropped ticks "
        "| step p99 (ms) | relay p99 (ms) | sim p99 (ms) | uploads/s 200 "
        "| uploads/s 429 (+ closed) | telemetry msgs/s per client | page live |"
    )
    lines = [head, "|" + "---|" * 14]
    order = {c: i for i, c in enumerate(CASES)}
    groups: dict[tuple[int, int, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["slots"], order[r["case"]], r["mode"]), []).append(r)
    for (slots, _, mode), rs in sorted(groups.items()):
        case = rs[0]["case"]
        m = {k: _median(rs, k) for k in rs[0] if k not in ("slots", "case", "mode", "other")}
        ws = (
            "–"
            if m["ws_per_client_hz"] != m["ws_per_client_hz"]
            else f"{m['ws_per_client_hz']:.1f}"
        )
        ups = "– | –"
        if case in N_UP:
            ups = f"{m['ok_per_s']:.1f} | {m['busy_per_s']:.1f} (+ {m['closed_per_s']:.0f})"
        live = [r["page_live"] for r in rs]
        lines.append(
            f"| {slots} | {case} | {mode} | {len(rs)} | {m['tick_hz']:.2f} "
            f"| {m['tick_hz'] / hz:.2f} | {m['dropped']:.0f} | {_ms(m['step_p99'])} "
            f"| {_ms(m['relay_p99'])} | {_ms(m['sim_p99'])} "
            f"| {ups} | {ws} | {'–' if live[0] is None else all(live)} |"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="measurement window per case")
    ap.add_argument("--ramp", type=float, default=2.0, help="load before the window starts (s)")
    ap.add_argument("--hz", type=float, default=30.0)
    ap.add_argument("--modes", default="process")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument(
        "--max-uploads",
        default="2,16",
        help="AAR_MAX_CONCURRENT_UPLOADS values (2: the default; 16: every uploader admitted)",
    )
    ap.add_argument("--repeat", type=int, default=1, help="runs (the table shows medians)")
    ap.add_argument("--detail", action="store_true", help="print every timing's p50/p99/max")
    args = ap.parse_args()
    cases = [c.strip() for c in args.cases.split(",")]
    rows: list[dict[str, Any]] = []
    print(f"cpus: {os.cpu_count()}, nominal {args.hz:g} Hz, {args.seconds:g} s per case")
    for run in range(args.repeat):
        if args.repeat > 1:
            print(f"run {run + 1}/{args.repeat}", flush=True)
        for slots in (int(x) for x in args.max_uploads.split(",")):
            for mode in args.modes.split(","):
                rows += measure_mode(
                    mode.strip(), args.hz, args.seconds, args.ramp, slots, cases, args.detail
                )
    print()
    print(table(rows, args.hz))
    print(
        "\nMedians over the runs. step: p99 over the window (/history) of the time from a "
        "tick's deadline to its result being available (process mode: the worker's deadline "
        "to the worker releasing the tick; thread mode: the loop's deadline to step() "
        "returning); relay: from the worker's deadline to the record being ready to publish "
        "in the web server's process (process mode); sim: the worker's own compute time per "
        "tick. 429 (+ closed): uploads refused with 429, plus those whose connection the "
        "server closed after its early 429 while the client was still sending the body."
    )
    others = [(r["slots"], r["case"], r["mode"], r["other"]) for r in rows if r["other"]]
    if others:
        print("other upload answers:", others)
    return 0


if __name__ == "__main__":
    sys.exit(main())
