"""The service under an attacker's requests (``AAR_TOKEN`` set): every answer is a fast 4xx.

* token checked on the headers, before any body byte is read (401);
* bodies bounded while they stream and on their declared length (413);
* images refused on their headers before decoding (413/400), decoding off the event loop;
* upload / calibration concurrency (429 + Retry-After);
* strict JSON models: NaN, Infinity, unknown fields → 422 naming the field, valid JSON body;
* implausible calibrations → 422 naming the field, the simulation keeps stepping;
* Host (DNS rebinding) → 400, foreign Origin → 403 (POST and the telemetry WebSocket).
"""

from __future__ import annotations

import asyncio
import functools
import gc
import itertools
import json
import math
import os
import select
import socket
import struct
import sys
import threading
import time
import weakref
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse
from starlette.websockets import WebSocketDisconnect

from app.calibration import plausibility as calibration_checks
from app.server.main import create_app
from app.service.image_guard import ImageHeaderError, peek_header
from app.service.settings import Settings
from app.service.upload_pool import ExecutorFactory
from tests.support.fake_sim import FakeSim  # the tests' fake step source
from tests.support.inline_sim import inline_sim
from tests.support.service_settings import service_settings
from tests.support.upload_executor import thread_uploads

REPO = Path(__file__).resolve().parents[2]
PAIR = REPO / "sample_data" / "pair_1000mm"
TOKEN = "s3cret"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _settings(tmp_path: Path, **kw: Any) -> Settings:
    return service_settings(tmp_path, **{"sim_auto_restart_s": None, "token": TOKEN, **kw})


def _app(
    tmp_path: Path,
    real_sim: bool = False,
    upload_executor: ExecutorFactory | None = None,
    **kw: Any,
) -> FastAPI:
    factory = None if real_sim else inline_sim(lambda cfg, cal: FakeSim(cfg, cal))
    return create_app(
        _settings(tmp_path, **kw), source_factory=factory, upload_executor=upload_executor
    )


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(_app(tmp_path)) as c:
        yield c


def _strict_json(text: str) -> Any:
    """Parse as strict JSON: NaN/Infinity tokens are an error."""

    def refuse(token: str) -> None:
        raise ValueError(f"non-standard JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


# ---- crafted image headers ------------------------------------------------------------------
def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_header_only(width: int, height: int, depth: int = 8, colour: int = 0) -> bytes:
    """A PNG whose IHDR declares ``width × height`` with only a few bytes of image data."""
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 4096, 9)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", idat)
        + _png_chunk(b"IEND", b"")
    )


def jpeg_header_only(width: int, height: int, comps: int = 3) -> bytes:
    app0 = b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    comp = b"".join(bytes([i + 1, 0x11, 0]) for i in range(comps))
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 8 + 3 * comps, 8, height, width, comps) + comp
    return b"\xff\xd8" + app0 + sof + b"\xff\xda\x00\x08\x01\x01\x00\x00\x3f\x00" + b"\xff\xd9"


def bmp_header_only(width: int, height: int) -> bytes:
    info = struct.pack("<IiiHHIIiiII", 40, width, height, 1, 24, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 54 + 16, 0, 0, 54) + info + b"\x00" * 16


def tiff_header_only(width: int, height: int, spp: int = 1) -> bytes:
    entries = [
        struct.pack("<HHII", 256, 4, 1, width),
        struct.pack("<HHII", 257, 4, 1, height),
        struct.pack("<HHIHH", 258, 3, 1, 8, 0),
        struct.pack("<HHIHH", 277, 3, 1, spp, 0),
    ]
    ifd = struct.pack("<H", len(entries)) + b"".join(entries) + struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", 8) + ifd


# ---- an ASGI driver that records how much of the body the app consumed -----------------------
async def _drive(
    app: Any,
    method: str,
    path: str,
    headers: dict[str, str],
    chunks: Iterator[bytes],
    client: tuple[str, int] = ("127.0.0.1", 40000),
) -> tuple[int, dict[str, str], Any, int]:
    consumed = 0
    sent: list[dict[str, Any]] = []
    finished = False

    async def receive() -> dict[str, Any]:
        nonlocal consumed, finished
        if finished:
            await asyncio.sleep(0)
            return {"type": "http.disconnect"}
        try:
            chunk = next(chunks)
        except StopIteration:
            finished = True
            return {"type": "http.request", "body": b"", "more_body": False}
        consumed += len(chunk)
        return {"type": "http.request", "body": chunk, "more_body": True}

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": method,
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "query_string": b"",
        "root_path": "",
        "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
        "client": client,
        "server": ("127.0.0.1", 8000),
        "state": {},
    }
    await app(scope, receive, send)
    starts = [m for m in sent if m["type"] == "http.response.start"]
    assert len(starts) == 1, sent
    resp_headers = {k.decode(): v.decode() for k, v in starts[0]["headers"]}
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return starts[0]["status"], resp_headers, _strict_json(body.decode()), consumed


def _drive_sync(c: TestClient, *args: Any, **kw: Any) -> tuple[int, dict[str, str], Any, int]:
    assert c.portal is not None
    return c.portal.call(functools.partial(_drive, c.app, *args, **kw))


def _endless(chunk_mb: float = 1.0, count: int = 1000) -> Iterator[bytes]:
    chunk = b"\x00" * int(chunk_mb * 1e6)
    for _ in range(count):
        yield chunk


PART_HEAD = b'--xyz\r\nContent-Disposition: form-data; name="left"; filename="l.png"\r\n\r\n'


def _endless_upload(chunk_mb: float = 1.0) -> Iterator[bytes]:
    """A well-formed multipart stream whose file part never ends."""
    return itertools.chain([PART_HEAD], _endless(chunk_mb))


MULTIPART = {"content-type": "multipart/form-data; boundary=xyz", "host": "localhost"}


# ---- 1. token before body ----------------------------------------------------------------------
def test_401_before_any_body_byte_is_read(client: TestClient) -> None:
    # a declared 1 GB upload and an endless chunked one: answered 401, nothing consumed
    for headers in (
        {**MULTIPART, "content-length": str(10**9)},
        {**MULTIPART, "transfer-encoding": "chunked"},
        {**MULTIPART, "authorization": "Bearer wrong", "transfer-encoding": "chunked"},
    ):
        status, h, body, consumed = _drive_sync(
            client, "POST", "/api/v1/stereo", headers, _endless()
        )
        assert status == 401, body
        assert body["detail"] == "missing or wrong bearer token"
        assert h["www-authenticate"] == "Bearer"
        assert consumed == 0
    # every mutating route, including the checkerboard one, before the body
    for method, path in (
        ("POST", "/api/v1/calibration/checkerboard"),
        ("PUT", "/api/v1/calibration"),
        ("PUT", "/api/v1/sim/config"),
        ("POST", "/api/v1/sim/stop"),
        ("POST", "/api/v1/recording/start"),
        ("DELETE", "/api/v1/anything"),
    ):
        status, _, _, consumed = _drive_sync(
            client, method, path, {"host": "localhost", "content-length": "5"}, iter([b"hello"])
        )
        assert (status, consumed) == (401, 0), (method, path)


@contextmanager
def _live_server(app: FastAPI) -> Iterator[int]:
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert server.started, "uvicorn did not start"
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(15)


def _raw_request(
    port: int, head: str, body_chunks: Iterator[bytes] | None = None
) -> tuple[str, int, float]:
    """Send ``head`` (and chunks until the server answers); → (status line, bytes sent, s)."""
    t0 = time.perf_counter()
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head.encode())
        for chunk in body_chunks or ():
            readable, _, _ = select.select([sock], [], [], 0)
            if readable:
                break
            try:
                sock.sendall(b"%x\r\n" % len(chunk) + chunk + b"\r\n")
            except OSError:  # the server answered and closed
                break
            sent += len(chunk)
        data = b""
        while b"\r\n" not in data:
            part = sock.recv(4096)
            if not part:
                break
            data += part
    return data.split(b"\r\n", 1)[0].decode(), sent, time.perf_counter() - t0


def test_real_server_answers_huge_declared_bodies_at_once(tmp_path: Path) -> None:
    app = _app(tmp_path, max_upload_mb=0.5)
    with _live_server(app) as port:
        head = (
            "POST /api/v1/stereo HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
            "Content-Type: multipart/form-data; boundary=x\r\nContent-Length: 1000000000\r\n{auth}\r\n"
        )
        # no token: 401 on the headers alone (1 GB declared, not one body byte sent)
        line, _, dt = _raw_request(port, head.format(port=port, auth=""))
        assert line.startswith("HTTP/1.1 401"), line
        assert dt < 2.0
        # with the token: 413 on the declared length, again before any body byte
        line, _, dt = _raw_request(
            port, head.format(port=port, auth=f"Authorization: Bearer {TOKEN}\r\n")
        )
        assert line.startswith("HTTP/1.1 413"), line
        assert dt < 2.0
        # chunked (no length): 413 once the count passes 2 × 0.5 + 1 = 2 MB
        chunked = (
            f"POST /api/v1/stereo HTTP/1.1\r\nHost: localhost:{port}\r\n"
            f"Authorization: Bearer {TOKEN}\r\n"
            "Content-Type: multipart/form-data; boundary=x\r\nTransfer-Encoding: chunked\r\n\r\n"
        )
        line, sent, _ = _raw_request(
            port, chunked.replace("boundary=x", "boundary=xyz"), _endless_upload(0.25)
        )
        assert line.startswith("HTTP/1.1 413"), line
        assert sent < 30e6  # of a 100 MB stream (socket buffers hold a few MB)
        # the server is fine afterwards
        ok = _raw_request(port, f"GET /api/v1/healthz HTTP/1.1\r\nHost: localhost:{port}\r\n\r\n")
        assert ok[0].startswith("HTTP/1.1 200"), ok


# ---- 2. body limits ------------------------------------------------------------------------------
def test_413_on_streamed_and_declared_oversized_bodies(tmp_path: Path) -> None:
    with TestClient(_app(tmp_path, max_upload_mb=0.5)) as c:
        # stereo: 2 × 0.5 + 1 = 2 MB; a chunked 1000 MB stream is stopped after ≤ 3 MB
        headers = {**MULTIPART, **{k.lower(): v for k, v in AUTH.items()}}
        status, h, body, consumed = _drive_sync(
            c, "POST", "/api/v1/stereo", headers, _endless_upload()
        )
        assert status == 413, body
        assert "AAR_MAX_REQUEST_MB" in body["detail"] and h["connection"] == "close"
        assert consumed <= 3_000_000 + len(PART_HEAD)
        # JSON routes: 256 kB
        status, _, body, consumed = _drive_sync(
            c,
            "PUT",
            "/api/v1/sim/config",
            {
                "host": "localhost",
                "content-type": "application/json",
                "authorization": AUTH["Authorization"],
            },
            _endless(0.1),
        )
        assert status == 413 and "AAR_MAX_JSON_KB" in body["detail"]
        assert consumed <= 300_000
        # a declared length over the limit: 413 on the header
        r = c.put(
            "/api/v1/calibration",
            content=b"{" + b" " * 300_000 + b"}",
            headers={**AUTH, "content-type": "application/json"},
        )
        assert r.status_code == 413 and "AAR_MAX_JSON_KB" in r.json()["detail"]
        r = c.post("/api/v1/stereo", headers=AUTH, files={"left": ("l.png", b"\0" * 2_500_000)})
        assert r.status_code == 413 and "AAR_MAX_REQUEST_MB" in r.json()["detail"]
        assert c.get("/api/v1/healthz").json()["loop_alive"]


# ---- 3. image guard -------------------------------------------------------------------------------
def test_peek_header_reads_real_images() -> None:
    grey = np.zeros((48, 64), np.uint8)
    colour = np.zeros((48, 64, 3), np.uint8)
    cases = {
        ".png": (grey, ("png", 64, 48, 1, 8)),
        ".tiff": (colour, ("tiff", 64, 48, 3, 8)),
        ".jpg": (colour, ("jpeg", 64, 48, 3, 8)),
        ".bmp": (colour, ("bmp", 64, 48, 3, 8)),
    }
    for ext, (img, want) in cases.items():
        h = peek_header(cv2.imencode(ext, img)[1].tobytes())
        assert (h.format, h.width, h.height, h.channels, h.bit_depth) == want, ext
    h16 = peek_header(cv2.imencode(".png", np.zeros((5, 7, 4), np.uint16))[1].tobytes())
    assert (h16.width, h16.height, h16.channels, h16.bit_depth) == (7, 5, 4, 16)
    assert h16.decoded_bytes == 7 * 5 * 4 * 2
    for junk in (b"GIF89a....", b"RIFF\0\0\0\0WEBPVP8 ", b"hello", b"\x89PNG\r\n\x1a\nshort"):
        with pytest.raises(ImageHeaderError):
            peek_header(junk)


@pytest.mark.parametrize(
    "name,data",
    [
        ("png grey", png_header_only(20000, 20000)),
        ("png rgb", png_header_only(20000, 20000, 8, 2)),
        ("png rgba16", png_header_only(20000, 20000, 16, 6)),
        ("jpeg", jpeg_header_only(20000, 20000)),
        ("bmp", bmp_header_only(20000, 20000)),
        ("tiff", tiff_header_only(20000, 20000)),
    ],
)
def test_huge_image_refused_on_its_header_fast(
    client: TestClient, monkeypatch: pytest.MonkeyPatch, name: str, data: bytes
) -> None:
    from app.server.routers import stereo
    from app.service.upload_pool import UploadPool

    def no_decode(*a: Any, **k: Any) -> Any:
        raise AssertionError("decoder reached")

    # every decode is behind the upload pool (the one path), or the dashboard's lazy images
    monkeypatch.setattr(UploadPool, "run", no_decode)
    monkeypatch.setattr(stereo, "decode_upload_image", no_decode)
    assert len(data) < 5000
    ok = (PAIR / "left.png").read_bytes()
    t0 = time.perf_counter()
    r = client.post(
        "/api/v1/stereo", headers=AUTH, files={"left": ("l.png", data), "right": ("r.png", ok)}
    )
    dt = time.perf_counter() - t0
    assert r.status_code == 413, r.text
    detail = r.json()["detail"]
    assert "20000x20000" in detail and "AAR_MAX_IMAGE_PIXELS" in detail, detail
    assert dt < 0.5, dt


def test_image_guard_size_format_and_off_loop_decoding(
    client: TestClient, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from app.service import upload_pool

    ok = (PAIR / "left.png").read_bytes()
    # under the absolute limit but not the calibration's 1280x1024: 422 before decoding
    r = client.post(
        "/api/v1/stereo",
        headers=AUTH,
        files={
            "left": ("l.png", png_header_only(4000, 3000)),
            "right": ("r.png", png_header_only(4000, 3000)),
        },
    )
    assert (
        r.status_code == 422 and "does not match the calibration (1280x1024)" in r.json()["detail"]
    )
    # an unsupported format (GIF): 400 naming the accepted ones
    r = client.post(
        "/api/v1/stereo",
        headers=AUTH,
        files={"left": ("l.gif", b"GIF89a" + b"\0" * 64), "right": ("r.png", ok)},
    )
    assert r.status_code == 400 and "PNG, JPEG, BMP or TIFF" in r.json()["detail"]
    # with an injected thread executor, decoding happens in a worker thread (no event loop
    # running there); by default in a worker process (tests/service/test_processes.py)
    threads: list[bool] = []
    original = upload_pool.decode_upload_image

    def spy(data: bytes, name: str) -> np.ndarray:
        try:
            asyncio.get_running_loop()
            threads.append(False)
        except RuntimeError:
            threads.append(True)
        return original(data, name)

    monkeypatch.setattr(upload_pool, "decode_upload_image", spy)
    with TestClient(_app(tmp_path, upload_executor=thread_uploads)) as threaded:
        r = threaded.post(
            "/api/v1/stereo",
            headers=AUTH,
            files={"left": ("l.png", ok), "right": ("r.png", (PAIR / "right.png").read_bytes())},
        )
    assert r.status_code == 200, r.text
    assert threads == [True, True]


def test_opencv_pixel_limit_is_set_before_cv2_loads() -> None:
    import subprocess

    code = (
        "import sys, numpy as np\n"
        "import app.server.main\n"
        "from app.service import image_guard\n"
        "import cv2, os\n"
        "assert image_guard.OPENCV_LIMIT_ACTIVE, 'cv2 loaded first'\n"
        "print(os.environ['OPENCV_IO_MAX_IMAGE_PIXELS'])\n"
        "buf = cv2.imencode('.png', np.zeros((3000, 2000), np.uint8))[1]\n"
        "try:\n"
        "    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)\n"
        "    print('decoded' if img is not None else 'refused')\n"
        "except cv2.error:\n"
        "    print('refused')\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_IO_MAX_IMAGE_PIXELS"}
    env["AAR_MAX_IMAGE_PIXELS"] = "5000000"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["5000000", "refused"]


# ---- 4. concurrency -------------------------------------------------------------------------------
def test_429_with_retry_after_when_slots_are_taken(client: TestClient) -> None:
    limits = client.app.state.limits  # type: ignore[attr-defined]
    ok_l, ok_r = (PAIR / "left.png").read_bytes(), (PAIR / "right.png").read_bytes()
    files = {"left": ("l.png", ok_l), "right": ("r.png", ok_r)}
    with limits["uploads"].hold():
        r = client.post("/api/v1/stereo", headers=AUTH, files=files)
        assert r.status_code == 429, r.text
        assert r.headers["retry-after"] == "2"
        assert "busy" in r.json()["detail"]
        # other routes are not affected
        assert client.post("/api/v1/sim/stop", headers=AUTH).status_code == 200
    assert limits["uploads"].in_use == 0
    assert client.post("/api/v1/stereo", headers=AUTH, files=files).status_code == 200
    assert limits["uploads"].in_use == 0  # released after the request
    with limits["calibrations"].hold():
        r = client.post(
            "/api/v1/calibration/checkerboard",
            headers=AUTH,
            files=[("left", ("a.png", ok_l)), ("right", ("b.png", ok_r))],
        )
        assert r.status_code == 429 and r.headers["retry-after"] == "2"
    # without a token a busy route still answers 401 first (no slot information leaks)
    with limits["uploads"].hold():
        assert client.post("/api/v1/stereo", files=files).status_code == 401


# ---- 5. checkerboard needs the token ------------------------------------------------------------
def test_checkerboard_needs_the_token(client: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    files = [("left", ("left_00.png", b"x")), ("right", ("right_00.png", b"x"))]
    url = "/api/v1/calibration/checkerboard"
    assert client.post(url, files=files).status_code == 401
    assert client.post(url, files=files, headers={"Authorization": "Bearer no"}).status_code == 401
    r = client.post(url, files=files, headers=AUTH)
    assert r.status_code == 400 and "is not a decodable image" in r.json()["detail"]
    # defence in depth: the route's own dependency (a bare app without the guard)
    from app.server.routers.checkerboard import router

    bare = FastAPI()
    bare.include_router(router, prefix="/api/v1")
    monkeypatch.setenv("AAR_TOKEN", TOKEN)
    with TestClient(bare) as b:
        assert b.post(url, files=files).status_code == 401
        assert b.post(url, files=files, headers=AUTH).status_code == 400


def test_checkerboard_images_refused_on_headers(client: TestClient) -> None:
    url = "/api/v1/calibration/checkerboard"
    big = png_header_only(5000, 4000)  # 20 Mpx > AAR_MAX_CALIBRATION_PIXELS (16.8 Mpx)
    r = client.post(
        url, headers=AUTH, files=[("left", ("left_00.png", big)), ("right", ("right_00.png", big))]
    )
    assert r.status_code == 413 and "5000x4000" in r.json()["detail"]
    for form in (
        {"square_mm": "inf"},
        {"square_mm": "nan"},
        {"max_rms_px": "Infinity"},
        {"board": "500x500"},
    ):
        files = [("left", ("left_00.png", b"x")), ("right", ("right_00.png", b"x"))]
        r = client.post(url, headers=AUTH, files=files, data=form)
        assert r.status_code == 422, (form, r.text)
        _strict_json(r.text)


# ---- 6. strict request models ----------------------------------------------------------------------
@pytest.mark.parametrize(
    "raw,field,echo",
    [
        ('{"closure_speed_mps": NaN}', "closure_speed_mps", "NaN"),
        ('{"tick_hz": Infinity}', "tick_hz", "Infinity"),
        ('{"noise_sigma": -Infinity}', "noise_sigma", "-Infinity"),
        ('{"turbulance": "severe"}', "turbulance", "severe"),
        ('{"seed": 1, "extra": {"x": NaN}}', "extra", {"x": "NaN"}),
    ],
)
def test_nan_infinity_unknown_fields_are_422_naming_the_field(
    client: TestClient, raw: str, field: str, echo: Any
) -> None:
    before = client.get("/api/v1/sim/config").json()
    r = client.put(
        "/api/v1/sim/config", content=raw, headers={**AUTH, "content-type": "application/json"}
    )
    assert r.status_code == 422, r.text
    body = _strict_json(r.text)  # valid JSON: no NaN/Infinity tokens
    assert body["field"] == field
    assert body["detail"][0]["loc"] == ["body", field]
    assert body["detail"][0]["input"] == echo
    assert client.get("/api/v1/sim/config").json() == before


def test_non_finite_query_and_calibration_values_are_422(client: TestClient) -> None:
    for value in ("nan", "inf", "-inf"):
        r = client.get("/api/v1/history", params={"seconds": value})
        assert r.status_code == 422 and _strict_json(r.text)["field"] == "seconds"
    cal = client.get("/api/v1/calibration").json()
    for bad in ("[NaN, 0, -28.3]", "[-111.4, Infinity, 0]"):
        raw = json.dumps({**cal, "T": "@T@"}).replace('"@T@"', bad)
        r = client.put(
            "/api/v1/calibration", content=raw, headers={**AUTH, "content-type": "application/json"}
        )
        assert r.status_code == 422 and _strict_json(r.text)["field"] == "T", r.text


# ---- 7. implausible calibrations -------------------------------------------------------------------
def _mutated(base: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    data = json.loads(json.dumps(base))
    target: Any = data
    keys: list[Any] = [int(k) if k.isdigit() else k for k in path.split("/")]
    for k in keys[:-1]:
        target = target[k]
    target[keys[-1]] = value
    return data


IMPLAUSIBLE = [
    ("left/K/0/0", 1e-320, "left.K", "fx"),
    ("left/K/0/0", 10.0, "left.K", "fx"),
    ("right/K/1/1", 2e5, "right.K", "fy"),
    ("left/K/0/2", -5.0, "left.K", "principal point"),
    ("right/K/1/2", 5000.0, "right.K", "principal point"),
    ("left/K/0/1", 500.0, "left.K", "skew"),
    ("T", [1e300, 0.0, 0.0], "T", "|T|"),
    ("T", [0.5, 0.0, 0.0], "T", "|T|"),
    ("T", [20000.0, 0.0, 0.0], "T", "|T|"),
    ("left/dist", [1e200, 0.0, 0.0, 0.0, 0.0], "left.dist", "distortion"),
    ("right/dist", [0.0, 11.0, 0.0, 0.0, 0.0], "right.dist", "distortion"),
    ("left/dist", [-5.0, 0.0, 0.0, 0.0, 0.0], "left.dist", "folds"),
    ("image_size", [8000, 6000], "image_size", "AAR_MAX_CALIBRATION_PIXELS"),
    ("image_size", [1e9, 1e9], "image_size", "each side"),
    ("image_size", [8, 8], "image_size", "each side"),
    ("unit", "mm", "unit", "unknown field"),
    ("left/Kk", [[1, 0, 0]], "left.Kk", "unknown field"),
]


def test_implausible_calibrations_are_422_and_the_simulation_keeps_stepping(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    created: list[weakref.ref[Any]] = []
    real_cls = calibration_checks.StereoCalibration

    class Tracked(real_cls):  # type: ignore[misc, valid-type]
        @classmethod
        def from_dict(cls, data: Any) -> Any:
            calib = real_cls.from_dict(data)
            created.append(weakref.ref(calib))
            return calib

    monkeypatch.setattr(calibration_checks, "StereoCalibration", Tracked)
    with TestClient(_app(tmp_path, real_sim=True, tick_hz=20.0)) as c:
        base = c.get("/api/v1/calibration").json()
        for path, value, field, words in IMPLAUSIBLE:
            r = c.put("/api/v1/calibration", json=_mutated(base, path, value), headers=AUTH)
            assert r.status_code == 422, (path, value, r.text)
            body = _strict_json(r.text)
            assert body["field"] == field, (path, body)
            assert words in body["detail"], (path, body)
        assert c.get("/api/v1/calibration").json() == base
        assert c.post("/api/v1/calibration/rollback", headers=AUTH).status_code == 409
        # refused calibrations are not kept anywhere
        gc.collect()
        assert created and all(ref() is None for ref in created)
        # the simulation still steps, without errors
        h0 = c.get("/api/v1/healthz").json()
        deadline = time.time() + 20
        while time.time() < deadline and c.get("/api/v1/healthz").json()["ticks"] < h0["ticks"] + 5:
            time.sleep(0.1)
        h1 = c.get("/api/v1/healthz").json()
        assert h1["ticks"] >= h0["ticks"] + 5 and h1["errors"] == 0 and h1["sim_running"]
        # a plausible one is still accepted
        ok = _mutated(base, "T", [-120.0, 0.0, -20.0])
        assert c.put("/api/v1/calibration", json=ok, headers=AUTH).status_code == 200


# ---- 8. Host and Origin --------------------------------------------------------------------------
def test_untrusted_host_is_400(client: TestClient) -> None:
    for host in ("evil.example", "evil.example:8000", "127.0.0.1.nip.io", "bad host", ""):
        r = client.get("/api/v1/healthz", headers={"Host": host})
        assert r.status_code == 400, host
        assert "Host" in r.json()["detail"]
    for host in ("localhost", "localhost:8000", "127.0.0.1:8000", "[::1]:8000", "LOCALHOST."):
        assert client.get("/api/v1/healthz", headers={"Host": host}).status_code == 200, host
    # the in-process client's name is only accepted from the in-process client
    status, _, body, _ = _drive_sync(
        client,
        "GET",
        "/api/v1/healthz",
        {"host": "testserver"},
        iter(()),
        client=("203.0.113.7", 5555),
    )
    assert status == 400 and "testserver" in body["detail"]
    # … nor from a client that claims the in-process name through X-Forwarded-For
    r = client.get("/api/v1/healthz", headers={"X-Forwarded-For": "testclient"})
    assert r.status_code == 400
    with pytest.raises((WebSocketDenialResponse, WebSocketDisconnect)):
        with client.websocket_connect("/api/v1/telemetry", headers={"Host": "evil.example"}) as ws:
            ws.receive_text()


def test_trusted_hosts_setting(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    s = Settings(host="0.0.0.0")
    assert s.effective_trusted_hosts == ["localhost", "127.0.0.1", "::1"]
    assert Settings(host="10.1.2.3").effective_trusted_hosts[-1] == "10.1.2.3"
    monkeypatch.setenv("AAR_TRUSTED_HOSTS", "dock.lan, *.example.org")
    monkeypatch.setenv("AAR_ALLOWED_ORIGINS", '["http://ops.example.org:9000"]')
    s = Settings()
    assert s.effective_trusted_hosts == ["dock.lan", "*.example.org"]
    assert s.allowed_origins == ["http://ops.example.org:9000"]
    with TestClient(_app(tmp_path, trusted_hosts=["*"])) as c:
        assert c.get("/api/v1/healthz", headers={"Host": "anything.example"}).status_code == 200
    with TestClient(_app(tmp_path, trusted_hosts=["dock.lan", "*.example.org"])) as c:
        assert c.get("/api/v1/healthz", headers={"Host": "a.example.org"}).status_code == 200
        assert c.get("/api/v1/healthz", headers={"Host": "dock.lan:8000"}).status_code == 200
        assert c.get("/api/v1/healthz", headers={"Host": "localhost"}).status_code == 400


def test_foreign_origin_is_403_on_mutations_and_websocket(tmp_path: Path) -> None:
    app = _app(tmp_path, allowed_origins=["http://ops.example.org:9000"])
    with TestClient(app) as c:
        for origin in (
            "http://evil.example",
            "null",
            "http://localhost:9999",
            "https://testserver:444",
        ):
            r = c.post("/api/v1/sim/stop", headers={**AUTH, "Origin": origin})
            assert r.status_code == 403, origin
            assert "cross-origin" in r.json()["detail"]
        # before the token check: a foreign page learns nothing about the token
        assert (
            c.post("/api/v1/sim/stop", headers={"Origin": "http://evil.example"}).status_code == 403
        )
        # same origin, an allowed origin, and no Origin (curl) are fine
        for headers in (
            {"Origin": "http://testserver"},
            {"Origin": "http://localhost:8000", "Host": "localhost:8000"},
            {"Origin": "http://ops.example.org:9000"},
            {},
        ):
            assert c.post("/api/v1/sim/start", headers={**AUTH, **headers}).status_code == 200, (
                headers
            )
        # reads are not refused (the browser's CORS keeps a foreign page from reading them)
        assert (
            c.get("/api/v1/healthz", headers={"Origin": "http://evil.example"}).status_code == 200
        )
        # the telemetry WebSocket
        with pytest.raises(WebSocketDenialResponse) as denied:
            with c.websocket_connect(
                "/api/v1/telemetry", headers={"Origin": "http://evil.example"}
            ):
                pass
        assert denied.value.status_code == 403
        assert "cross-origin" in denied.value.json()["detail"]
        with c.websocket_connect(
            "/api/v1/telemetry", headers={"Origin": "http://testserver"}
        ) as ws:
            assert json.loads(ws.receive_text())["source"] == "sim"
        with c.websocket_connect("/api/v1/telemetry") as ws:
            assert math.isfinite(json.loads(ws.receive_text())["t_s"])
