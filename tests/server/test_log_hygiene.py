"""Log hygiene: no token in the access log (a real ``aar-dock serve``), accept() failures at
the descriptor limit logged once per interval (asyncio's handler called as at EMFILE)."""

from __future__ import annotations

import asyncio
import errno
import logging
from pathlib import Path

import httpx
import pytest

from app.server.log_hygiene import AcceptErrorLimiter, QueryRedactor, redact_query
from tests.support.live_server import serve, ws_connect


def test_query_values_are_redacted() -> None:
    assert redact_query("/api/v1/stream/push?token=s3cret") == "/api/v1/stream/push?token=***"
    assert redact_query("/a?tok%65n=s3cret&b=2") == "/a?tok%65n=***&b=***"
    assert redact_query("/no/query") == "/no/query"
    record = logging.LogRecord(
        "uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
        ("127.0.0.1:5", "GET", "/x?token=s3cret", "1.1", 200), None,
    )  # fmt: skip
    QueryRedactor().filter(record)
    assert "s3cret" not in record.getMessage() and "token=***" in record.getMessage()


def test_accept_failures_are_logged_once_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    limiter = AcceptErrorLimiter(interval_s=60.0)
    logger = logging.getLogger("asyncio")
    installed = list(logger.filters)  # a serve run earlier in this process installed its own
    for f in installed:
        logger.removeFilter(f)
    logger.addFilter(limiter)
    loop = asyncio.new_event_loop()
    try:
        with caplog.at_level(logging.ERROR, logger="asyncio"):
            for _ in range(1000):  # as asyncio's accept loop does at EMFILE, per attempt
                loop.call_exception_handler(
                    {
                        "message": "socket.accept() out of system resource",
                        "exception": OSError(errno.EMFILE, "Too many open files"),
                    }
                )
    finally:
        loop.close()
        logger.removeFilter(limiter)
        for f in installed:
            logger.addFilter(f)
    lines = [r for r in caplog.records if "accept()" in r.getMessage()]
    assert len(lines) == 1 and lines[0].exc_info is None
    assert "Too many open files" in lines[0].getMessage()


def test_the_token_never_reaches_the_log(tmp_path: Path) -> None:
    with serve(tmp_path, {"AAR_TOKEN": "s3cret", "AAR_LOG_LEVEL": "info"}) as (_, port, log):
        base = f"http://127.0.0.1:{port}/api/v1"
        assert httpx.get(f"{base}/healthz?token=s3cret").status_code == 200
        ws_connect(port, "/api/v1/stream/push?token=s3cret").close()
        assert httpx.get(f"{base}/stream?token=s3cret&x=1").status_code == 200
        text = log.read_text()
    assert "token=***" in text and "s3cret" not in text, text[-2000:]


def test_served_with_opencvs_own_pixel_limit(tmp_path: Path) -> None:
    """``aar-dock serve`` loads OpenCV after the image guard set its pixel limit (the second
    line of defence against a header that lies): no warning that the limit is not in force."""
    with serve(tmp_path, {"AAR_LOG_LEVEL": "info"}) as (_, port, log):
        assert httpx.get(f"http://127.0.0.1:{port}/api/v1/healthz").status_code == 200
        text = log.read_text()
    assert "Application startup complete" in text, text[-2000:]
    assert "pixel limit" not in text, text[-2000:]
