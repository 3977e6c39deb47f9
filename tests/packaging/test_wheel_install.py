"""The package as a user gets it: a wheel, installed in a clean venv outside the repository.

``pip wheel . --no-deps``, a fresh venv in a temporary directory, ``pip install`` of the wheel
(dependencies from PyPI; pip's cache makes the second run fast), then from a working
directory outside the repository: ``aar-dock process --sample`` gives a lock on a shipped
sample pair (checked against its shipped ``truth.json``) and ``aar-dock serve`` answers
``/api/v1/healthz`` and serves the operators' page, its script and the favicon.

Needs the network (or a warm pip cache) for the dependencies: marked ``slow``. No container
engine runs here, so the Dockerfile is checked against the package instead (not slow).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from app.resources import REPO_ROOT
from tests.support.waiting import stop_process

INSTALL_TIMEOUT_S = 900
SERVE_TIMEOUT_S = 120


def _clean_env(home: Path) -> dict[str, str]:
    """The environment without this checkout's venv, PYTHONPATH or AAR_* settings."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME") and not k.startswith("AAR_")
    }
    env["XDG_DATA_HOME"] = str(home / "xdg")  # recordings go here, not to ~ or the checkout
    return env


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float) -> str:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{cmd} -> {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(url: str) -> tuple[int, bytes, str]:
    with urllib.request.urlopen(url, timeout=5) as r:
        return r.status, r.read(), r.headers.get("content-type", "")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """(venv bin dir, a working directory outside the repository, environment)."""
    base = tmp_path_factory.mktemp("wheel")
    assert REPO_ROOT not in base.resolve().parents
    wheels = base / "dist"
    env = _clean_env(base)
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(REPO_ROOT),
            "--no-deps",
            "-q",
            "-w",
            str(wheels),
        ],
        base,
        env,
        INSTALL_TIMEOUT_S,
    )
    (wheel,) = wheels.glob("aar_dock-*.whl")
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], base, env, 120)
    bin_dir = venv / "bin"
    _run([str(bin_dir / "pip"), "install", "-q", str(wheel)], base, env, INSTALL_TIMEOUT_S)
    work = base / "elsewhere"
    work.mkdir()
    return bin_dir, work, env


@pytest.mark.slow
def test_installed_package_is_not_the_checkout(installed):
    bin_dir, work, env = installed
    out = _run(
        [str(bin_dir / "python"), "-c", "import app; print(app.__file__)"], work, env, 60
    ).strip()
    assert Path(out).resolve().is_relative_to(bin_dir.parent.resolve())


@pytest.mark.slow
def test_process_a_shipped_sample(installed):
    bin_dir, work, env = installed
    exe = str(bin_dir / "aar-dock")
    names = _run([exe, "process", "--list-samples"], work, env, 120).split()
    assert "pair_1000mm" in names
    assert "checkerboard" not in names  # the 13 MB checkerboard set stays in the repository
    result = json.loads(_run([exe, "process", "--sample", "pair_1000mm", "--json"], work, env, 300))
    assert result["lock"] is True and len(result["leds"]) == 5
    # the truth shipped next to the pair (not the repository's copy)
    code = "from app.resources import sample_data_dir; print(sample_data_dir())"
    data = Path(_run([str(bin_dir / "python"), "-c", code], work, env, 60).strip())
    assert data.resolve().is_relative_to(bin_dir.parent.resolve())
    truth = json.loads((data / "pair_1000mm" / "truth.json").read_text())
    assert np.linalg.norm(np.subtract(result["drogue"]["center_mm"], truth["center_mm"])) < 0.5


@pytest.mark.slow
def test_serve_health_and_page(installed):
    bin_dir, work, env = installed
    port, viser_port = _free_port(), _free_port()
    cmd = [str(bin_dir / "aar-dock"), "serve", "--port", str(port), "--viser-port", str(viser_port)]
    log = (work / "serve.log").open("w")
    proc = subprocess.Popen(cmd, cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + SERVE_TIMEOUT_S
        health = None
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                status, body, _ = _get(base + "/api/v1/healthz")
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                time.sleep(0.5)
                continue
            health = json.loads(body)
            if status == 200 and health["ticks"] > 0:
                break
            time.sleep(0.5)
        assert proc.poll() is None, (work / "serve.log").read_text()
        assert health is not None and health["status"] == "ok" and health["ticks"] > 0, health
        assert health["viser"] is True
        status, page, ctype = _get(base + "/")
        assert status == 200 and "text/html" in ctype and b"aar-dock" in page
        status, script, _ = _get(base + "/static/app.js")
        assert status == 200 and b"/telemetry" in script
        status, icon, ctype = _get(base + "/favicon.ico")
        assert status == 200 and icon and ctype.startswith("image/")
        status, _, ctype = _get(f"http://127.0.0.1:{viser_port}/")
        assert status == 200 and "text/html" in ctype
        # nothing written into the working directory (recordings live under XDG_DATA_HOME)
        assert sorted(p.name for p in work.iterdir()) == ["serve.log"]
    finally:
        stop_process(proc, 30)
        log.close()
    shutil.rmtree(work / "__pycache__", ignore_errors=True)


def test_dockerfile_agrees_with_the_package() -> None:
    """What the image relies on exists: the health URL is a route of the app, the command is
    the package's script, and the package data is in the build context before ``pip install``."""
    import tomllib

    from app.server.main import create_app
    from app.service.settings import Settings

    text = (REPO_ROOT / "Dockerfile").read_text()
    lines = [ln.strip() for ln in text.splitlines()]
    (health,) = {m for m in text.split("'") if m.startswith("http://127.0.0.1:8000/")}
    path = health.removeprefix("http://127.0.0.1:8000")
    app = create_app(Settings(viser_enabled=False, sim_autostart=False))  # type: ignore[call-arg]
    assert "get" in app.openapi()["paths"].get(path, {}), path
    assert 'CMD ["aar-dock", "serve"]' in lines
    scripts = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert "aar-dock" in scripts
    install = next(i for i, ln in enumerate(lines) if ln.startswith("RUN pip install ."))
    copied = {ln.split()[1] for ln in lines[:install] if ln.startswith("COPY ")}
    assert {"static", "sample_data", "app", "pyproject.toml"} <= copied, copied
    for link in ("static", "sample_data"):  # what the package data globs go through
        target = (REPO_ROOT / "app" / "_data" / link).resolve()
        assert target == (REPO_ROOT / link).resolve(), target
    ignored = (REPO_ROOT / ".dockerignore").read_text().split()
    assert "sample_data/pair_1000mm" not in ignored and "static" not in ignored


def test_page_assets_and_defaults_come_from_the_package(tmp_path, monkeypatch) -> None:
    """The page, its worker, the favicon and the calibration are the package's; recordings go
    under XDG_DATA_HOME, not into the working directory."""
    from fastapi.testclient import TestClient

    from app import resources as paths
    from app.server.main import create_app
    from app.service.settings import Settings

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.chdir(tmp_path)
    settings = Settings(viser_enabled=False, sim_autostart=False)  # type: ignore[call-arg]
    assert settings.recordings_dir == tmp_path / "xdg" / "aar-dock" / "recordings"
    assert settings.static_dir == paths.static_dir() and settings.calibration.is_file()
    assert paths.data_root().parent == Path(__import__("app").__file__).parent
    with TestClient(create_app(settings)) as c:
        page = c.get("/")
        assert page.status_code == 200 and "/static/app.js" in page.text
        icon = c.get("/favicon.ico")
        assert icon.status_code == 200 and icon.headers["content-type"] == "image/svg+xml"
        worker = c.get("/static/telemetry_worker.js")
        assert worker.status_code == 200 and "new WebSocket" in worker.text
        rec = c.post("/api/v1/recording/start")
        assert rec.status_code == 200, rec.text
        assert c.post("/api/v1/recording/stop").status_code == 200
    # the recording went to XDG_DATA_HOME; nothing was written into the working directory
    assert any((tmp_path / "xdg" / "aar-dock" / "recordings").iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["xdg"]
