"""The operators' page with a video source: ``aar-dock serve --source video:...`` in a
subprocess, Debian's chromium via Playwright. The *Frame source* panel shows the source, its
rate, drops and the stream guidance, and switches the source (token-protected)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from tests.support.streams_sequence import cached_sequence, write_avi
from tests.support.waiting import stop_process, wait_for_server

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"]


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _status(base: str) -> dict:
    with urllib.request.urlopen(base + "/api/v1/stream", timeout=3) as r:
        return json.loads(r.read())


def test_page_shows_the_video_source_and_switches_it(tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    left, right = write_avi(cached_sequence(40), tmp_path)
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_TOKEN="tok")
    env.update(AAR_LOG_LEVEL="warning", AAR_RECORDINGS_DIR=str(tmp_path / "rec"))
    cmd = [sys.executable, "-m", "app", "serve", "--no-viser", "--no-sim", "--loop"]
    cmd += ["--source", f"video:{left},{right}", "--port", str(port)]
    log = (tmp_path / "serve.log").open("wb")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_for_server(proc, lambda: _status(base) is not None, tmp_path / "serve.log")
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page()
            page.goto(base + "/", wait_until="domcontentloaded")
            page.wait_for_function(
                "document.getElementById('src-state').textContent === 'running' && "
                "parseFloat(document.getElementById('src-fps').textContent) > 5 && "
                "parseFloat(document.getElementById('g-closure').textContent) > 0.3",
                timeout=30_000,
            )
            assert page.text_content("#src-spec") == f"video:{left},{right}"
            assert page.text_content("#src-drops") == "0 / 0 / 0"
            assert page.text_content("#g-mode") in ("tracked", "acquired")
            page.fill("#src-input", "push")
            page.click("#src-form button[type=submit]")  # no token yet: refused
            page.wait_for_function(
                "document.getElementById('src-msg').textContent.startsWith('401')"
            )
            page.fill("#token", "tok")
            page.click("#src-form button[type=submit]")
            page.wait_for_function(
                "document.getElementById('src-msg').textContent === 'source: push'"
            )
            browser.close()
        assert _status(base)["source"] == "push"
    finally:
        stop_process(proc)
        log.close()


def test_page_shows_a_failing_stream_as_degraded(tmp_path: Path) -> None:
    """A push source whose pairs all fail: the header says DEGRADED with the stream and why."""
    from playwright.sync_api import sync_playwright
    from websockets.sync.client import connect

    from app.streams.protocol import encode_message
    from tests.support.hostile_images import undecodable_png

    seq = cached_sequence(2)
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_LOG_LEVEL="warning")
    env.update(AAR_RECORDINGS_DIR=str(tmp_path / "rec"), AAR_STREAM_FAILURE_STREAK="3")
    env.update(AAR_STREAM_RESTART_BACKOFF_S="60")  # stays restarting while the page looks
    cmd = [sys.executable, "-m", "app", "serve", "--no-viser", "--no-sim", "--source", "push"]
    log = (tmp_path / "serve.log").open("wb")
    proc = subprocess.Popen(cmd + ["--port", str(port)], cwd=ROOT, env=env, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_for_server(proc, lambda: _status(base) is not None, tmp_path / "serve.log")
        bad_left, bad_right = undecodable_png(seq.lefts[0]), undecodable_png(seq.rights[0])
        with connect(f"ws://127.0.0.1:{port}/api/v1/stream/push", max_size=None) as ws:
            for i in range(3):
                ws.send(encode_message(bad_left, bad_right, t_s=i / 30, seq=i))
                wait_for_server(
                    proc,
                    lambda i=i: _status(base)["consecutive_failures"] > i,
                    tmp_path / "serve.log",
                    timeout_s=10,
                )
        assert _status(base)["state"] == "restarting"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page()
            page.goto(base + "/", wait_until="domcontentloaded")
            page.wait_for_selector("#health:not([hidden])", timeout=15_000)
            text = page.text_content("#health") or ""
            assert text.startswith("DEGRADED") and "stream:push" in text and "failed" in text
            browser.close()
    finally:
        stop_process(proc)
        log.close()
