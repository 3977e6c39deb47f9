"""Real-browser end-to-end test: ``aar-dock serve`` in a subprocess, Debian's chromium via
Playwright. Fails (does not skip) when /usr/bin/chromium is missing.

Screenshots go to ``artifacts/`` (gitignored). With ``AAR_UPDATE_SCREENSHOT=1`` the page
screenshot is also written to ``docs/screenshot.png`` (the README's picture).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.browser

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "artifacts"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
PAIR = REPO / "sample_data" / "pair_1000mm"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=3) as r:
        return json.loads(r.read())


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory):
    port, viser_port = _free_port(), _free_port()
    while viser_port == port:
        viser_port = _free_port()
    exe = shutil.which("aar-dock", path=str(Path(sys.executable).parent)) or "aar-dock"
    rec_dir = tmp_path_factory.mktemp("recordings")
    log_path = tmp_path_factory.mktemp("log") / "serve.log"
    log = log_path.open("w")
    proc = subprocess.Popen(
        [
            exe,
            "serve",
            "--port",
            str(port),
            "--viser-port",
            str(viser_port),
            "--recordings-dir",
            str(rec_dir),
        ],
        cwd=REPO,
        stdout=log,
        stderr=subprocess.STDOUT,
        env={**os.environ, "AAR_TOKEN": ""},
    )
    base = f"http://127.0.0.1:{port}"
    deadline = time.time() + 60
    ok = False
    while time.time() < deadline and proc.poll() is None:
        try:
            if _get_json(base + "/api/v1/healthz")["ticks"] > 0:
                ok = True
                break
        except OSError:
            pass
        time.sleep(0.3)
    if not ok:
        proc.terminate()
        proc.wait(10)
        pytest.fail("aar-dock serve did not come up:\n" + log_path.read_text()[-3000:])
    yield base, viser_port
    proc.terminate()
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


def test_chromium_present() -> None:
    assert Path(CHROMIUM).exists(), (
        "chromium missing: apt-get install -y chromium (the browser test must not be skipped)"
    )


def _views_in_frame(base: str) -> tuple[bool, dict]:
    """Is every docking target inside the embedded view, as its browser reports its camera?"""
    from app.viz.framing import project

    view = _get_json(base + "/api/v1/scene/view")
    targets = np.asarray(view["targets_m"], float)
    embedded = [c for c in view["clients"] if c["panel_minimized"]]
    if len(targets) == 0 or not embedded:
        return False, view
    for c in embedded:
        uv = project(
            targets,
            position=c["position"],
            look_at=c["look_at"],
            up=c["up"],
            fov_rad=c["fov_rad"],
            width_px=c["width_px"],
            height_px=c["height_px"],
        )
        inside = (
            np.isfinite(uv).all()
            and (uv[:, 0] > 0).all()
            and (uv[:, 0] < c["width_px"]).all()
            and (uv[:, 1] > 0).all()
            and (uv[:, 1] < c["height_px"]).all()
        )
        if not inside:
            return False, {**view, "uv": uv.tolist()}
    return True, view


def test_operators_page_end_to_end(service) -> None:
    assert Path(CHROMIUM).exists(), "chromium missing at /usr/bin/chromium"
    from playwright.sync_api import sync_playwright

    base, viser_port = service
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1500, "height": 1000})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            missing: list[str] = []  # e.g. /favicon.ico used to 404
            page.on("response", lambda r: missing.append(r.url) if r.status == 404 else None)
            page.goto(base + "/", wait_until="domcontentloaded")
            # 1. telemetry arrives over the WebSocket and the numbers change over 2 s
            page.wait_for_function(
                "document.getElementById('t_s').textContent !== '–'", timeout=30_000
            )
            lock_text = page.inner_text("#lock")
            assert lock_text in ("LOCK", "NO LOCK")
            t1 = page.inner_text("#t_s")
            rel1 = page.inner_text("#rel-x")
            page.wait_for_timeout(2000)
            t2 = page.inner_text("#t_s")
            rel2 = page.inner_text("#rel-x")
            assert (t1, rel1) != (t2, rel2), (t1, t2)
            assert float(page.inner_text("#tick-rate")) > 0
            # 1b. both camera images are shown and follow the stream; a locked frame's image
            #     carries the LED ids drawn on it (the caption names them)
            page.wait_for_function(
                "['cam-left', 'cam-right'].every(id => document.getElementById(id).naturalWidth"
                " === 480 && document.getElementById(id).dataset.seq)",
                timeout=30_000,
            )
            seqs1 = page.eval_on_selector_all("#cameras img", "ims => ims.map(i => i.dataset.seq)")
            page.wait_for_function(
                "s => [...document.querySelectorAll('#cameras img')]"
                ".every((im, k) => im.dataset.seq !== s[k])",
                arg=seqs1,
                timeout=20_000,
            )
            page.wait_for_function(
                "document.getElementById('cam-left-cap').textContent.includes('· LOCK ·')"
                " && document.getElementById('cam-left-cap').dataset.ids.split(',').length >= 3",
                timeout=30_000,
            )
            cap = page.inner_text("#cam-left-cap")
            assert "LEDs " in cap and any(str(i) in cap.split("LEDs ")[1] for i in range(1, 6))
            # 2. the viser iframe connects and draws a non-blank canvas
            src = page.get_attribute("#viser-frame", "src")
            assert src is not None and f":{viser_port}" in src
            frame = None
            deadline = time.time() + 30
            while frame is None and time.time() < deadline:
                frame = next((f for f in page.frames if f":{viser_port}" in f.url), None)
                if frame is None:
                    page.wait_for_timeout(200)
            assert frame is not None, "viser iframe did not load"
            frame.wait_for_selector("canvas", timeout=60_000)
            page.wait_for_timeout(5000)  # software WebGL: let a few frames render
            shot = page.locator("#viser-frame").screenshot(path=str(ARTIFACTS / "viser_frame.png"))
            img = cv2.imdecode(np.frombuffer(shot, np.uint8), cv2.IMREAD_COLOR)
            assert img is not None
            # blank = one flat colour; a rendered scene has many distinct colours and contrast
            small = img[::4, ::4].reshape(-1, 3)
            distinct = len(np.unique(small // 8, axis=0))
            assert float(img.std()) > 10.0 and distinct > 50, (img.std(), distinct)
            # 2b. framing: the embedded view's control panel is minimized and the camera its
            #     browser reports sees the drogue (centre and rim), the probe and the receiver
            #     (nose, tail, wing tips) — projected with that camera, all inside the canvas
            deadline = time.time() + 20
            framed, view = _views_in_frame(base)
            while not framed and time.time() < deadline:
                page.wait_for_timeout(500)
                framed, view = _views_in_frame(base)
            assert framed, json.dumps(view)[-1500:]
            # 3. upload a stereo pair through the form: 5 matched LEDs in the table
            page.set_input_files("#left-file", str(PAIR / "left.png"))
            page.set_input_files("#right-file", str(PAIR / "right.png"))
            page.click("#upload-form button[type=submit]")
            page.wait_for_function(
                "document.querySelectorAll('#led-table tbody tr').length === 5", timeout=60_000
            )
            assert "5 LEDs matched" in page.inner_text("#upload-summary")
            ids = page.eval_on_selector_all(
                "#led-table tbody tr", "rows => rows.map(r => r.cells[0].textContent)"
            )
            assert sorted(ids) == ["1", "2", "3", "4", "5"]
            # the overlay canvas holds the image and the drawn detections (not blank)
            px = page.eval_on_selector(
                "#upload-left",
                "c => { const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
                " let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i] + d[i+1] + d[i+2] > 150) n++;"
                " return n; }",
            )
            assert px > 100
            # the service's drawing of the uploaded pair (the live cameras' producer)
            drawn = page.eval_on_selector("#upload-left", "c => c.dataset.ids")
            assert sorted(drawn.split(",")) == ["1", "2", "3", "4", "5"]
            page.wait_for_timeout(1500)
            page.screenshot(path=str(ARTIFACTS / "operators_page.png"), full_page=True)
            if os.environ.get("AAR_UPDATE_SCREENSHOT"):
                page.screenshot(path=str(REPO / "docs" / "screenshot.png"), full_page=True)
            # 3b. a failed upload clears the previous result: no stale table, image or summary
            bad = ARTIFACTS / "not_an_image.png"
            bad.write_bytes(b"this is not a PNG")
            page.set_input_files("#left-file", str(bad))
            page.set_input_files("#right-file", str(bad))
            page.click("#upload-form button[type=submit]")
            page.wait_for_function(
                "document.getElementById('upload').dataset.state === 'failed'", timeout=30_000
            )
            assert page.inner_text("#upload-status").startswith("failed: 400")
            assert page.is_hidden("#upload-result")
            assert page.eval_on_selector_all("#led-table tbody tr", "rows => rows.length") == 0
            assert page.inner_text("#upload-summary") == ""
            # 3c. Stop shows STOPPED in the banner; Start brings the lock state back
            page.click("#btn-stop")
            page.wait_for_function(
                "document.getElementById('lock').textContent === 'STOPPED'", timeout=10_000
            )
            page.click("#btn-start")
            page.wait_for_function(
                "['LOCK', 'NO LOCK'].includes(document.getElementById('lock').textContent)",
                timeout=20_000,
            )
            # 4. record a few seconds from the page, then replay the .viser file offline in
            #    the locally served viser client
            #    (issue 33: the panel says how long a recording can run before it starts,
            #    and the time left during it)
            page.wait_for_function(
                "document.getElementById('rec-budget').textContent.includes('can run')",
                timeout=20_000,
            )
            page.click("#rec-start")
            page.wait_for_function(
                "document.getElementById('rec-msg').textContent.startsWith('recording')",
                timeout=10_000,
            )
            page.wait_for_function(
                "document.getElementById('rec-budget').textContent.includes(' left')",
                timeout=10_000,
            )
            page.wait_for_timeout(1000)
            page.click("#rec-stop")
            page.wait_for_selector("#rec-list a:has-text('replay 3-D')", timeout=20_000)
            replay_href = page.get_attribute("#rec-list a:has-text('replay 3-D')", "href")
            assert replay_href is not None and "playbackPath=" in replay_href
            replay = browser.new_page(viewport={"width": 900, "height": 600})
            logs: list[str] = []
            replay.on("console", lambda m: logs.append(m.text))
            replay.goto(base + replay_href)
            replay.wait_for_selector("canvas", timeout=60_000)
            deadline = time.time() + 30
            while not any("File loaded" in m for m in logs) and time.time() < deadline:
                replay.wait_for_timeout(200)
            assert any("File loaded" in m for m in logs), logs[:10]
            replay.wait_for_timeout(3000)
            shot = replay.screenshot(path=str(ARTIFACTS / "replay.png"))
            rimg = cv2.imdecode(np.frombuffer(shot, np.uint8), cv2.IMREAD_COLOR)
            assert float(rimg.std()) > 10.0
            # 4b. the miss of the last drogue-plane crossing stays on screen (the record
            #     carries it on one tick only; the page used to show "–" right after)
            miss_shown = "/^\\d+\\.\\d{3} [✓✗]$/.test(document.getElementById('miss').textContent)"
            page.wait_for_function(miss_shown, timeout=90_000)
            page.wait_for_timeout(1500)  # later ticks have no miss: the value is kept
            assert page.evaluate(miss_shown), page.inner_text("#miss")
            # 5. the API docs render offline (local Swagger UI assets)
            docs = browser.new_page()
            external: list[str] = []
            docs.on(
                "request",
                lambda r: external.append(r.url) if not r.url.startswith(base) else None,
            )
            docs.goto(base + "/docs")
            docs.wait_for_selector(".swagger-ui .title", timeout=30_000)
            assert "aar-dock" in docs.inner_text(".swagger-ui .title")
            assert not external, external
            assert not errors, errors
            assert not missing, missing
        finally:
            browser.close()
