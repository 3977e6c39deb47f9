"""Log filters of the served app: no secrets in the access log, no log flood from accept().

* :class:`QueryRedactor` (loggers ``uvicorn.access`` and ``uvicorn.error``): every query
  parameter's value in a logged request path becomes ``***`` — ``?token=s3cret`` (the push
  WebSocket's documented token) never reaches a log file, whatever the parameter's spelling.
* :class:`AcceptErrorLimiter` (logger ``asyncio``, every event loop of the process):
  ``socket.accept() out of system resource`` (EMFILE at the file-descriptor limit) is logged
  once per interval with the number left out, not once per attempt with a traceback each.
"""

from __future__ import annotations

import logging
import re
import threading
import time

_QUERY_VALUE = re.compile(r"([?&][^=&#\s\"]*)=([^&#\s\"]*)")
ACCEPT_FAILURE = "socket.accept() out of system resource"


def redact_query(text: str) -> str:
    """``/push?token=abc&x=1`` → ``/push?token=***&x=***`` (only text after a ``?``)."""
    head, sep, tail = text.partition("?")
    if not sep:
        return text
    return head + _QUERY_VALUE.sub(r"\1=***", sep + tail)


class QueryRedactor(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and any(isinstance(a, str) and "?" in a for a in args):
            record.args = tuple(redact_query(a) if isinstance(a, str) else a for a in args)
        if isinstance(record.msg, str) and "?" in record.msg:
            record.msg = redact_query(record.msg)
        return True


class AcceptErrorLimiter(logging.Filter):
    def __init__(self, interval_s: float = 10.0) -> None:
        super().__init__()
        self.interval_s = interval_s
        self._last = -float("inf")
        self._suppressed = 0
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        if not isinstance(record.msg, str) or not record.msg.startswith(ACCEPT_FAILURE):
            return True
        now = time.monotonic()
        with self._lock:
            if now - self._last < self.interval_s:
                self._suppressed += 1
                return False
            self._last, suppressed, self._suppressed = now, self._suppressed, 0
        exc = record.exc_info[1] if record.exc_info else None
        record.msg = f"{ACCEPT_FAILURE}: {exc!r}" if exc is not None else ACCEPT_FAILURE
        if suppressed:
            record.msg += f" ({suppressed} more in the last {self.interval_s:g} s not logged)"
        record.msg += " (at the file-descriptor limit? see AAR_MAX_CONNECTIONS, AAR_FD_RESERVE)"
        record.args = None
        record.exc_info = None  # one line, no traceback
        record.exc_text = None
        return True


_installed: list[logging.Filter] = []


def install(accept_interval_s: float = 10.0) -> None:
    """Add the filters (once per process)."""
    if _installed:
        return
    redactor, limiter = QueryRedactor(), AcceptErrorLimiter(accept_interval_s)
    for name in ("uvicorn.access", "uvicorn.error"):
        logging.getLogger(name).addFilter(redactor)
    logging.getLogger("asyncio").addFilter(limiter)
    _installed.extend((redactor, limiter))
