"""Polling helper shared by the service tests."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_until(
    cond: Callable[[], bool], timeout_s: float = 10.0, what: str = "condition", poll_s: float = 0.02
) -> None:
    """Return as soon as ``cond()`` holds; fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(poll_s)
