"""The service app as the tests build it: its simulation's worker loop in the test's process
(``tests/support/inline_sim.py``) unless the test injects its own."""

from __future__ import annotations

from fastapi import FastAPI

from app.server.main import create_app
from app.service.clock import Clock
from app.service.settings import Settings
from app.service.sim_worker.proxy import ProcessSourceFactory
from app.service.upload_pool import ExecutorFactory
from tests.support.inline_sim import inline_sim


def service_app(
    settings: Settings,
    clock: Clock | None = None,
    *,
    source_factory: ProcessSourceFactory | None = None,
    upload_executor: ExecutorFactory | None = None,
) -> FastAPI:
    """``create_app`` with the docking simulation's worker loop in this process (default)."""
    return create_app(
        settings,
        clock,
        source_factory=source_factory or inline_sim(),
        upload_executor=upload_executor,
    )
