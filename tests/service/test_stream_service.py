"""Stream supervision (issue 23): a push source that fails is visible and restarts itself.

* 25 undecodable pushed pairs: ``/healthz`` is ``degraded`` and names ``stream:push``,
  ``/metrics`` says ``aar_stream_up 0``, the pusher is closed with 1013 and the reason;
* valid pairs pushed afterwards are processed again within 2 s, with no operator action;
* in push mode ``tick_rate_hz`` is the stream's rate, not the stopped simulation's;
* one pusher at a time (the second is refused with 1008), repeated/backward ``seq`` counted,
  an unparsable (deeply nested) header closed with 1007 and a reason;
* a stream thread that dies, or hangs while pushed pairs wait, is restarted by the watchdog.
"""

from __future__ import annotations

import json
import struct
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.service.settings import Settings
from app.streams.protocol import encode_message
from tests.support.hostile_images import undecodable_png
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.streams_sequence import cached_sequence
from tests.support.waiting import wait_until

PUSH = "/api/v1/stream/push"


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(
        tmp_path, **{**SIM_IDLE, "source": "push", "stream_restart_backoff_s": 0.2, **kw}
    )


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()


def _status(c: TestClient) -> dict[str, Any]:
    return c.get("/api/v1/stream").json()


def test_a_failing_push_stream_is_reported_and_restarts_itself(tmp_path: Path) -> None:
    seq = cached_sequence(8)
    bad_left, bad_right = undecodable_png(seq.lefts[0]), undecodable_png(seq.rights[0])
    with TestClient(service_app(_settings(tmp_path))) as c:
        assert c.get("/api/v1/healthz").json()["status"] == "ok"
        sent, closes = 0, []
        while sent < 25:  # the pusher reconnects when it is told the stream restarts
            with c.websocket_connect(PUSH) as ws:
                try:
                    while sent < 25:
                        before = _status(c)["consecutive_failures"]
                        ws.send_bytes(encode_message(bad_left, bad_right, t_s=sent / 30, seq=sent))
                        sent += 1
                        wait_until(
                            lambda b=before: (
                                _status(c)["consecutive_failures"] > b
                                or _status(c)["state"] == "restarting"
                            ),
                            10,
                            f"bad pair {sent} counted",
                        )
                    ws.send_text("stats")
                    ws.receive_text()  # a reply, or the close below
                except WebSocketDisconnect as exc:
                    closes.append((exc.code, exc.reason))
        health = c.get("/api/v1/healthz").json()
        assert health["status"] == "degraded", health
        stream = [x for x in health["components"] if x["name"] == "stream:push"]
        assert stream and stream[0]["status"] == "degraded" and stream[0]["reason"]
        assert health["source"] == "push"
        assert 'aar_stream_up{source="push"} 0' in c.get("/api/v1/metrics").text
        # the pusher was told: close 1013 with the reason (20 failed pairs in a row)
        assert closes and closes[0][0] == 1013 and "failed pairs" in closes[0][1], closes
        # valid pairs: processed again within 2 s, nobody switched the source
        frames0 = _status(c)["frames"]
        t0 = time.monotonic()
        with c.websocket_connect(PUSH) as ws:
            i = 0
            while _status(c)["frames"] == frames0:
                assert time.monotonic() - t0 < 2.0, _status(c)
                msg = encode_message(
                    _png(seq.lefts[i % 8]), _png(seq.rights[i % 8]), t_s=1 + i / 30, seq=100 + i
                )
                ws.send_bytes(msg)
                i += 1
                time.sleep(0.05)
        st = _status(c)
        assert st["restarts"] >= 1 and st["state"] == "running"
        wait_until(lambda: c.get("/api/v1/healthz").json()["status"] == "ok", 5, "healthz ok")
        health = c.get("/api/v1/healthz").json()
        assert health["tick_rate_hz"] < 100  # the stream's rate, not the stopped simulation's


def test_one_pusher_at_a_time_seq_counters_and_unparsable_header(tmp_path: Path) -> None:
    seq = cached_sequence(4)
    left, right = _png(seq.lefts[0]), _png(seq.rights[0])
    with TestClient(service_app(_settings(tmp_path))) as c:
        with c.websocket_connect(PUSH) as first:
            with pytest.raises(WebSocketDisconnect) as exc:
                with c.websocket_connect(PUSH) as second:
                    second.receive_text()
            assert exc.value.code == 1008 and "AAR_PUSH_MAX_CLIENTS" in exc.value.reason
            for s in (5, 5, 3, 6):  # a duplicate, one backwards
                first.send_bytes(encode_message(left, right, t_s=s / 30, seq=s))
            first.send_text("stats")
            replies = [json.loads(first.receive_text()) for _ in range(2)]
        stats = [r for r in replies if "received" in r][0]
        assert stats["seq_duplicate"] == 1 and stats["seq_out_of_order"] == 1
        text = c.get("/api/v1/metrics").text
        assert 'aar_push_seq_duplicate_total{source="push"} 1' in text
        assert 'aar_push_seq_out_of_order_total{source="push"} 1' in text
        # a header nested ~1900 deep: a clear close reason, not a dropped connection
        header = b"[" * 1900 + b"]" * 1900
        with c.websocket_connect(PUSH) as ws:
            ws.send_bytes(b"AARP" + struct.pack("<HI", 1, len(header)) + header)
            with pytest.raises(WebSocketDisconnect) as exc:
                ws.receive_text()
        assert exc.value.code == 1007 and "nested too deeply" in exc.value.reason


class _ThreadKiller(BaseException):
    """Not an ``Exception``: ends the stream thread as a bug outside the pair loop would."""


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_dead_stream_thread_and_a_stall_are_seen_and_restarted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from app.streams.processor import StreamProcessor

    seq = cached_sequence(4)
    real = StreamProcessor.process
    mode = {"now": "kill"}

    def process(self: StreamProcessor, frame: Any, kind: Any) -> Any:
        if mode["now"] == "kill":
            mode["now"] = "ok"
            raise _ThreadKiller()
        if mode["now"] == "hang":
            time.sleep(3.0)
        return real(self, frame, kind)

    monkeypatch.setattr(StreamProcessor, "process", process)
    settings = _settings(tmp_path, stream_stall_s=0.5)
    with TestClient(service_app(settings)) as c:

        def push(i: int) -> None:
            msg = encode_message(_png(seq.lefts[i % 4]), _png(seq.rights[i % 4]), t_s=i, seq=i)
            with c.websocket_connect(PUSH) as ws:
                ws.send_bytes(msg)
                ws.send_text("stats")
                ws.receive_text()

        push(0)  # the thread dies on it
        wait_until(lambda: _status(c)["restarts"] == 1, 5, "restart after the thread died")
        push(1)
        wait_until(lambda: _status(c)["frames"] == 1, 20, "a pair processed after the restart")
        mode["now"] = "hang"
        push(2)  # the thread hangs on this one …
        push(3)  # … and this one waits unread: stalled
        wait_until(
            lambda: (
                "unread" in (c.get("/api/v1/healthz").json()["components"][1]["reason"] or "")
                or _status(c)["restarts"] == 2
            ),
            5,
            "the stall seen",
        )
        wait_until(lambda: _status(c)["restarts"] == 2, 5, "restart after the stall")
        mode["now"] = "ok"
        push(4)
        wait_until(lambda: _status(c)["frames"] >= 2, 20, "pairs processed again")
