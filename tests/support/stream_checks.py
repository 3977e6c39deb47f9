"""Checks shared by the stream tests: the history of one source, and two results compared."""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi.testclient import TestClient


def history_records(c: TestClient, source: str) -> list[dict[str, Any]]:
    return [r for r in c.get("/api/v1/history?seconds=600").json() if r["source"] == source]


def assert_same_pose(a: dict[str, Any], b: dict[str, Any]) -> None:
    """Equal results: lock, reason, ids and pixels exactly; 3-D to 1e-9 mm (summation order)."""
    assert (a["lock"], a["reason"]) == (b["lock"], b["reason"])
    assert [led["id"] for led in a["leds"]] == [led["id"] for led in b["leds"]]
    for la, lb in zip(a["leds"], b["leds"], strict=True):
        assert la["left_px"] == lb["left_px"] and la["right_px"] == lb["right_px"]
        assert np.allclose(la["xyz_mm"], lb["xyz_mm"], rtol=0, atol=1e-9)
    if a["drogue"] is not None:
        assert np.allclose(a["drogue"]["center_mm"], b["drogue"]["center_mm"], rtol=0, atol=1e-9)
