"""The service's settings as the tests start it: no 3-D port, recordings under the test's
temporary directory; each test file adds what it needs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from app.service.settings import Settings

#: the simulation not started by itself (its worker in the test's process:
#: ``tests.support.service_app``; the uploads: ``tests.support.upload_executor``)
SIM_IDLE: dict[str, Any] = dict(sim_autostart=False)


def service_settings(tmp_path: Path, **kw: Any) -> Settings:
    """``Settings`` with ``viser_enabled=False``, ``recordings_dir=tmp_path / "rec"`` and ``kw``."""
    base: dict[str, Any] = dict(viser_enabled=False, recordings_dir=tmp_path / "rec")
    base.update(kw)
    return Settings(**base)
