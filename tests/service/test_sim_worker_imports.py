"""The simulation worker's child side stays light: it loads nothing of the web server and
nothing of the runtime outside its own package."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_worker_module_imports_no_server_module_outside_its_package() -> None:
    code = (
        "import json, sys\n"
        "import app.service.sim_worker.worker\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith(('app.server', 'app.service')))))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "app.service.sim_worker.worker" in loaded
    others = [
        m
        for m in loaded
        if m != "app.service"
        and m != "app.service.sim_worker"
        and not m.startswith("app.service.sim_worker.")
    ]
    assert others == []
