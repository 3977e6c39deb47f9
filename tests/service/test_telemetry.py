"""WS /telemetry on a real ``aar-dock serve``: what a client sends is ignored, text or binary,
and its stream goes on."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_client_messages_text_or_binary_do_not_stop_the_stream(tmp_path: Path) -> None:
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_RECORDINGS_DIR=str(tmp_path), AAR_LOG_LEVEL="warning", PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "app", "serve", "--no-viser", "--port", str(port)]
    proc = subprocess.Popen(
        cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz").json()["ticks"] > 0:
                    break
            except (httpx.HTTPError, KeyError, ValueError):
                pass
            time.sleep(0.3)
        with connect(f"ws://127.0.0.1:{port}/api/v1/telemetry", open_timeout=10) as ws:
            first = json.loads(ws.recv(timeout=10))["seq"]
            ws.send(b"\x00\x01binary")
            ws.send("hello")
            seqs = [json.loads(ws.recv(timeout=5))["seq"] for _ in range(20)]
    finally:
        proc.terminate()
        proc.wait(15)
    assert seqs == sorted(seqs) and seqs[-1] > first + 10
