"""A thread's CPU priority: real-time (``SCHED_RR``) or a lower nice value, where permitted.

Used by the simulation worker (child side of :mod:`app.service.sim_worker`), the tick thread
and the web server's threads; it imports nothing of the server.
"""

from __future__ import annotations

import os
import threading

RT_PRIORITY = 1  # SCHED_RR priority asked for (the lowest real-time level)


def raise_thread_priority(nice: int, *, realtime: bool = False) -> str:
    """Raise the calling thread's CPU priority where permitted (Linux: each thread has its
    own; threads it starts later inherit it), silently keeping the default elsewhere.

    ``realtime``: ``SCHED_RR`` at :data:`RT_PRIORITY` first (root or CAP_SYS_NICE; the
    kernel's real-time throttling still leaves ≥ 5 % of each CPU to the others); then nice
    ``nice`` (never lowered). Returns what was obtained: ``"rr"``, ``"nice"`` or
    ``"default"``."""
    try:
        tid = threading.get_native_id()
    except AttributeError:  # pragma: no cover - no native thread ids
        return "default"
    if realtime:
        try:
            os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(RT_PRIORITY))
            return "rr"
        except (OSError, AttributeError):
            pass
    try:
        if os.getpriority(os.PRIO_PROCESS, tid) > nice:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        return "nice"
    except (OSError, AttributeError):
        return "default"
