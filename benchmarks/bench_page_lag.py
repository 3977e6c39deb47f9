"""How stale are the operators' page's numbers while the embedded 3-D view renders in software?

One ``aar-dock serve`` (vision in the loop, 30 Hz, viser on), headless Debian chromium (no GPU:
SwiftShader WebGL), the page at 1500×1000 with the 3-D view embedded. For each page version a
MutationObserver notes when the displayed ``t (s)`` changes; afterwards each displayed value is
matched to its record's publication time (``GET /api/v1/history``), so

    lag = when the page showed the value − when the server published it (same clock).

Versions: the page before issue 14 (``--old-rev``, default ``67c944f``: redraw on
requestAnimationFrame for every telemetry message) and the current one (``static/``: a 10 Hz
redraw timer, half-resolution 3-D view without GPU), each ``--seconds`` long, alternated
``--rounds`` times in the same run. Prints a table with medians and p95 per version.

    .venv/bin/python benchmarks/bench_page_lag.py [--seconds 20] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
OBSERVE = """() => {
  window.__shown = [];
  const el = document.getElementById('t_s'), src = document.getElementById('source');
  new MutationObserver(() => window.__shown.push([Date.now() / 1000, el.textContent, src.textContent]))
    .observe(el, {childList: true, characterData: true, subtree: true});
}"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(url: str) -> object:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def _static_dirs(tmp: Path, old_rev: str) -> dict[str, str]:
    """One static dir holding the current page at / and the old one under old/."""
    root = tmp / "static"
    shutil.copytree(REPO / "static", root)
    old = root / "old"
    old.mkdir()
    for name in ("index.html", "app.js", "style.css"):
        text = subprocess.run(
            ["git", "show", f"{old_rev}:static/{name}"],
            cwd=REPO,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        if name == "index.html":
            text = text.replace("/static/app.js", "/static/old/app.js")
            text = text.replace("/static/style.css", "/static/old/style.css")
        (old / name).write_text(text)
    return {"old": "/static/old/index.html", "new": "/"}


def _lags(shown: list[list], history: list[dict]) -> np.ndarray:
    """Seconds between a record's publication and the page showing its (run, t)."""
    by_t: dict[tuple[str, str], float] = {}
    for rec in history:
        if rec["source"] == "sim":  # the page shows "sim / run" and t with 2 decimals
            by_t[(f"sim / {rec['run']}", f"{rec['t_s']:.2f}")] = rec["wall_time"]
    out = [when - by_t[(src, t)] for when, t, src in shown if (src, t) in by_t]
    return np.asarray(out, float)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--old-rev", default="67c944f")
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    tmp = Path(tempfile.mkdtemp(prefix="aar-page-lag-"))
    pages = _static_dirs(tmp, args.old_rev)
    port, vport = _free_port(), _free_port()
    env = {
        **os.environ,
        "AAR_TOKEN": "",
        "AAR_STATIC_DIR": str(tmp / "static"),
        "AAR_HISTORY_S": "120",
        "AAR_SIM_AUTO_RESTART_S": "1",
        "XDG_DATA_HOME": str(tmp / "xdg"),
    }
    exe = str(Path(sys.executable).parent / "aar-dock")
    log = (tmp / "serve.log").open("w")
    proc = subprocess.Popen(
        [exe, "serve", "--port", str(port), "--viser-port", str(vport)],
        cwd=tmp,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    results: dict[str, list[np.ndarray]] = {"old": [], "new": []}
    try:
        for _ in range(240):
            try:
                if _get(base + "/api/v1/healthz")["ticks"] > 0:  # type: ignore[index]
                    break
            except OSError:
                time.sleep(0.5)
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu"]
            )
            for _ in range(args.rounds):
                for version in ("old", "new"):
                    page = browser.new_page(viewport={"width": 1500, "height": 1000})
                    page.goto(base + pages[version])
                    page.wait_for_selector("#viser-frame")
                    page.wait_for_timeout(5000)  # the 3-D view connects and starts drawing
                    page.evaluate(OBSERVE)
                    page.wait_for_timeout(args.seconds * 1000)
                    shown = page.evaluate("window.__shown")
                    page.close()
                    history = _get(base + f"/api/v1/history?seconds={args.seconds + 30:.0f}")
                    results[version].append(_lags(shown, history))  # type: ignore[arg-type]
            browser.close()
        health = _get(base + "/api/v1/healthz")
    finally:
        proc.terminate()
        proc.wait(30)
        log.close()
    print(
        f"page telemetry lag, {args.rounds} × {args.seconds:.0f} s per version, 3-D view embedded"
    )
    print(f"(server tick rate at the end: {health['tick_rate_hz']:.1f} Hz)")  # type: ignore[index]
    print("| page | values shown | shown per s | lag p50 (s) | lag p95 (s) | lag max (s) |")
    print("|---|---|---|---|---|---|")
    for version, label in (("old", f"before ({args.old_rev})"), ("new", "now")):
        lag = np.concatenate(results[version]) if results[version] else np.zeros(0)
        if len(lag) == 0:
            print(f"| {label} | 0 | 0 | – | – | – |")
            continue
        rate = len(lag) / (args.rounds * args.seconds)
        p50, p95, mx = np.percentile(lag, 50), np.percentile(lag, 95), lag.max()
        print(f"| {label} | {len(lag)} | {rate:.1f} | {p50:.3f} | {p95:.3f} | {mx:.3f} |")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
