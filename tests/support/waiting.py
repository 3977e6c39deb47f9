"""Polling and server-process helpers shared by the service tests."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import httpx


def wait_until(
    cond: Callable[[], bool], timeout_s: float = 10.0, what: str = "condition", poll_s: float = 0.02
) -> None:
    """Return as soon as ``cond()`` holds; fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(poll_s)


def wait_for_server(
    proc: subprocess.Popen[bytes], up: Callable[[], bool], log: Path, timeout_s: float = 60.0
) -> None:
    """Return once ``up()`` holds (connection errors count as not yet); fail the test with the
    server's log tail if the process exits or ``timeout_s`` passes first."""
    deadline = time.monotonic() + timeout_s
    while True:
        assert proc.poll() is None, log.read_text()[-2000:]
        assert time.monotonic() < deadline, "server did not come up"
        try:
            if up():
                return
        except (OSError, httpx.HTTPError):
            pass
        time.sleep(0.1)


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 10.0) -> None:
    """SIGTERM, then SIGKILL if it has not exited within ``timeout_s``."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
