"""The image guard (``app/service/image_guard.py``) against the decoder it protects.

An image can lie about its size: a TIFF whose directory says ImageWidth/ImageLength twice, a
PNG with a second IHDR, a strip larger than the image. The guard must read the size OpenCV
will allocate, or refuse the image before decoding:

* the hostile TIFF (6000 × 6000 first, 1280 × 1024 second: 35 KB) is refused with a 422 and a
  reason, on upload and on the push WebSocket, in a fresh process whose peak RSS grows by
  ≤ 50 MB (before the fix: 36 Mpx decoded, 1.4 s, +175 MB);
* Hypothesis mutates PNG/JPEG/BMP/TIFF headers: whenever the guard accepts W × H, OpenCV
  decodes exactly W × H or fails cleanly (never more: the decoding runs in a process whose
  OpenCV pixel limit would report it).
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.service.image_guard import (
    AmbiguousHeaderError,
    ImageHeaderError,
    ImageRefused,
    check,
    peek_header,
)
from tests.support.hostile_images import hostile_tiff, tiff

REPO = Path(__file__).resolve().parents[2]


# ---- hand-built images ------------------------------------------------------------------------


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


# ---- the guard's verdicts -----------------------------------------------------------------------
def test_tiff_size_written_twice_is_refused() -> None:
    data = hostile_tiff()
    assert len(data) < 40_000
    with pytest.raises(AmbiguousHeaderError, match="ImageWidth written twice"):
        peek_header(data)
    with pytest.raises(ImageRefused) as exc:
        check(data, "left", max_pixels=40_000_000)
    assert exc.value.status == 422 and "ambiguous image header" in exc.value.detail
    # the same size twice is refused too: one value per tag, no choice left to the decoder
    with pytest.raises(AmbiguousHeaderError):
        peek_header(tiff(64, 48, [(256, 3, 1, 64)]))
    # tags out of order (libtiff reads them anyway, first match wins): refused
    unsorted = tiff(64, 48, sort=False)
    swapped = unsorted[:10] + unsorted[22:34] + unsorted[10:22] + unsorted[34:]
    with pytest.raises(AmbiguousHeaderError, match="out of order"):
        peek_header(swapped)


@pytest.mark.parametrize(
    "extra,match",
    [
        ([(322, 3, 1, 4096), (323, 3, 1, 16)], "TileWidth 4096"),  # one 4096-wide tile
        ([(323, 3, 1, 60000), (322, 3, 1, 64)], "TileLength 60000"),
    ],
)
def test_tiff_tiles_larger_than_the_image_are_refused(
    extra: list[tuple[int, int, int, int]], match: str
) -> None:
    with pytest.raises(AmbiguousHeaderError, match=match):
        peek_header(tiff(64, 48, extra))


def test_tiff_strip_larger_than_the_image_is_refused() -> None:
    # OpenCV allocates RowsPerStrip × width × 4 bytes for one strip, whatever ImageLength says
    data = tiff(64, 48)
    patched = data.replace(
        struct.pack("<HHII", 278, 4, 1, 0xFFFFFFFF), struct.pack("<HHII", 278, 4, 1, 200_000)
    )
    with pytest.raises(AmbiguousHeaderError, match="RowsPerStrip 200000"):
        peek_header(patched)
    # a strip of the image's height, or "one strip" (2**32 - 1): accepted
    assert peek_header(data).pixels == 64 * 48
    ok = data.replace(
        struct.pack("<HHII", 278, 4, 1, 0xFFFFFFFF), struct.pack("<HHII", 278, 4, 1, 48)
    )
    assert peek_header(ok).pixels == 64 * 48


def test_tiff_size_tags_must_be_single_unsigned_values() -> None:
    data = tiff(64, 48)
    two = data.replace(
        struct.pack("<HHIHH", 256, 3, 1, 64, 0), struct.pack("<HHIHH", 256, 3, 2, 64, 9)
    )
    with pytest.raises(ImageHeaderError, match="2 values of ImageWidth"):
        peek_header(two)
    signed = data.replace(
        struct.pack("<HHIHH", 257, 3, 1, 48, 0), struct.pack("<HHIHH", 257, 8, 1, 48, 0)
    )
    with pytest.raises(ImageHeaderError, match="ImageLength of type 8"):
        peek_header(signed)


def test_tiff_orientation_that_transposes_is_read_as_decoded() -> None:
    data = tiff(40, 30, [(274, 3, 1, 6)])
    h = peek_header(data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert (h.width, h.height) == (30, 40) == (img.shape[1], img.shape[0])


def test_png_second_ihdr_and_apng_are_refused() -> None:
    png = cv2.imencode(".png", np.zeros((30, 40), np.uint8))[1].tobytes()
    second = _chunk(b"IHDR", struct.pack(">IIBBBBB", 6000, 6000, 8, 0, 0, 0, 0))
    with pytest.raises(AmbiguousHeaderError, match="second IHDR"):
        peek_header(png[:33] + second + png[33:])
    actl = _chunk(b"acTL", struct.pack(">II", 2, 0))
    with pytest.raises(ImageHeaderError, match="APNG"):
        peek_header(png[:33] + actl + png[33:])
    assert peek_header(png).pixels == 1200


# ---- hostile TIFF, upload and push, in a fresh process (time and peak RSS) ----------------------
_RSS_SCRIPT = r"""
import json, re, sys, time
from pathlib import Path
from fastapi.testclient import TestClient
from tests.support.fake_sim import FakeSim
from tests.support.hostile_images import hostile_tiff
from app.server.main import create_app
from app.service.settings import Settings
from app.streams.protocol import encode_message

def status():
    s = open("/proc/self/status").read()
    return {k: int(re.search(k + r":\s+(\d+)", s).group(1)) / 1024 for k in ("VmHWM", "VmRSS")}

from tests.support.upload_executor import thread_uploads
from tests.support.inline_sim import inline_sim
settings = Settings(viser_enabled=False, recordings_dir=Path(sys.argv[1]), sim_auto_restart_s=None)
# the uploads in this process's threads: the web process's memory is what is measured
app = create_app(settings, source_factory=inline_sim(lambda cfg, cal: FakeSim(cfg, cal)),
                 upload_executor=thread_uploads)
bad = hostile_tiff()
out = {}
with TestClient(app) as c:
    ok = Path("sample_data/pair_1000mm/left.png").read_bytes()
    assert c.post("/api/v1/stereo", files={"left": ("l.png", ok), "right": ("r.png", ok)}).status_code == 200
    base = status()
    open("/proc/self/clear_refs", "w").write("5")  # peak RSS := current RSS
    t0 = time.perf_counter()
    r = c.post("/api/v1/stereo", files={"left": ("l.tif", bad), "right": ("r.tif", bad)})
    out["upload"] = {"status": r.status_code, "detail": r.json()["detail"],
                     "s": time.perf_counter() - t0, "growth_mb": status()["VmHWM"] - base["VmRSS"]}
    assert c.put("/api/v1/stream/source", json={"source": "push"}).status_code == 200
    with c.websocket_connect("/api/v1/stream/push") as ws:
        base = status()
        open("/proc/self/clear_refs", "w").write("5")
        t0 = time.perf_counter()
        ws.send_bytes(encode_message(bad, bad, t_s=0.0, seq=0))
        ws.send_text("stats")
        first = json.loads(ws.receive_text())
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # until the pair is refused, decoded or failed
            st = c.get("/api/v1/stream").json()
            if st["rejected"] + st["frames"] + st["errors"] >= 1:
                break
            time.sleep(0.05)
        time.sleep(0.3)
        out["push"] = {"reply": first, "stream": st, "s": time.perf_counter() - t0,
                       "growth_mb": status()["VmHWM"] - base["VmRSS"]}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def hostile_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, object]]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run(
        [sys.executable, "-c", _RSS_SCRIPT, str(tmp_path_factory.mktemp("rec"))],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result: dict[str, dict[str, object]] = json.loads(proc.stdout.strip().splitlines()[-1])
    print(json.dumps(result, indent=1))
    return result


def test_hostile_tiff_upload_refused_before_decoding(
    hostile_run: dict[str, dict[str, object]],
) -> None:
    up = hostile_run["upload"]
    assert up["status"] == 422, up
    assert "ImageWidth written twice" in str(up["detail"]), up
    assert float(str(up["s"])) < 0.5, up
    assert float(str(up["growth_mb"])) <= 50, up


def test_hostile_tiff_push_refused_before_decoding(
    hostile_run: dict[str, dict[str, object]],
) -> None:
    push = hostile_run["push"]
    reply = push["reply"]
    assert isinstance(reply, dict) and "ImageWidth written twice" in reply.get("error", ""), push
    stream = push["stream"]
    assert isinstance(stream, dict) and stream["rejected"] == 1 and stream["frames"] == 0, push
    assert float(str(push["growth_mb"])) <= 50, push


# ---- fuzz: the guard never under-states what OpenCV decodes -------------------------------------
FUZZ_LIMIT_PX = 4_000_000  # OpenCV's own limit in the decoding process


def _decode(data: bytes) -> tuple[str, int, int, str]:
    """In the decoding process: ("ok", w, h, "") / ("limit", 0, 0, why) / ("fail", 0, 0, why)."""
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        text = str(exc)
        kind = "limit" if "CV_IO_MAX_IMAGE" in text else "fail"
        return kind, 0, 0, text[-200:]
    if img is None:
        return "fail", 0, 0, "None"
    return "ok", int(img.shape[1]), int(img.shape[0]), ""


@pytest.fixture(scope="module")
def decoder() -> Iterator[ProcessPoolExecutor]:
    """One spawned process with OpenCV's pixel limit set before cv2 loads: a decoder that
    wants more than the guard said is reported ("limit"), not allowed to allocate it."""
    saved = os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS")
    os.environ["OPENCV_IO_MAX_IMAGE_PIXELS"] = str(FUZZ_LIMIT_PX)
    pool = ProcessPoolExecutor(1, mp_context=get_context("spawn"))
    try:
        assert pool.submit(_decode, b"").result(timeout=120)[0] == "fail"  # started
    finally:
        if saved is None:
            os.environ.pop("OPENCV_IO_MAX_IMAGE_PIXELS", None)
        else:
            os.environ["OPENCV_IO_MAX_IMAGE_PIXELS"] = saved
    yield pool
    pool.shutdown(cancel_futures=True)


def _seeds() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 255, (24, 32), dtype=np.uint8)
    colour = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    seeds = {
        "png": cv2.imencode(".png", grey)[1].tobytes(),
        "png16": cv2.imencode(".png", colour.astype(np.uint16) * 257)[1].tobytes(),
        "jpeg": cv2.imencode(".jpg", colour)[1].tobytes(),
        "jpeg-progressive": cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[
            1
        ].tobytes(),
        "bmp": cv2.imencode(".bmp", colour)[1].tobytes(),
        "bmp-grey": cv2.imencode(".bmp", grey)[1].tobytes(),
        "tiff": cv2.imencode(".tiff", colour)[1].tobytes(),
        "tiff-hand": tiff(32, 24, [(274, 3, 1, 1)]),
        "tiff-tiled": tiff(32, 24, [(322, 3, 1, 16), (323, 3, 1, 16)]),
    }
    return seeds


SEEDS = _seeds()
# where the size fields are: most edits land there
_HOT = {"png": range(8, 40), "jpeg": range(0, 200), "bmp": range(0, 60), "tiff": range(0, 160)}


def _duplicate_entry(data: bytes, k: int, value: int) -> bytes:
    """A TIFF (II) with directory entry ``k`` written twice (the copy holding ``value``)."""
    (ifd,) = struct.unpack("<I", data[4:8])
    (n,) = struct.unpack("<H", data[ifd : ifd + 2])
    k %= n
    entry = data[ifd + 2 + 12 * k : ifd + 14 + 12 * k]
    copy = entry[:8] + struct.pack("<I", value)
    body = data[ifd + 2 : ifd + 2 + 12 * n]
    new_ifd = struct.pack("<H", n + 1) + body[: 12 * k] + copy + body[12 * k :]
    # offsets after the directory move by 12 bytes: append the new directory at the end
    return (
        data[:4] + struct.pack("<I", len(data)) + data[8:] + new_ifd + data[ifd + 2 + 12 * n :][:4]
    )


def _second_ihdr(data: bytes, width: int, height: int) -> bytes:
    return (
        data[:33]
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + data[33:]
    )


def _second_sof(data: bytes, width: int, height: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00"
    return data[:2] + sof + data[2:]


@st.composite
def hostile_images(draw: st.DrawFn) -> bytes:
    name = draw(st.sampled_from(sorted(SEEDS)))
    data = bytearray(SEEDS[name])
    family = name.split("-")[0].rstrip("16")
    structural = draw(st.integers(0, 3))
    size = draw(st.integers(1, 3000))
    if structural == 0 and family == "tiff" and data[:2] == b"II":
        data = bytearray(_duplicate_entry(bytes(data), draw(st.integers(0, 20)), size))
    elif structural == 0 and family == "png":
        data = bytearray(_second_ihdr(bytes(data), size, draw(st.integers(1, 3000))))
    elif structural == 0 and family == "jpeg":
        data = bytearray(_second_sof(bytes(data), size, draw(st.integers(1, 3000))))
    hot = _HOT[family]
    for _ in range(draw(st.integers(0, 4))):
        pos = draw(st.sampled_from(hot) | st.integers(0, len(data) - 1))
        if pos < len(data):
            if draw(st.booleans()):
                data[pos] = draw(st.integers(0, 255))
            else:  # a small 16-bit value (a plausible size) at pos
                data[pos : pos + 2] = struct.pack(
                    draw(st.sampled_from(["<H", ">H"])), draw(st.integers(0, 4000))
                )
    return bytes(data)


@settings(
    max_examples=int(os.environ.get("AAR_FUZZ_EXAMPLES", "600")),
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(data=hostile_images())
def test_guard_never_understates_the_decoded_size(
    decoder: ProcessPoolExecutor, data: bytes
) -> None:
    try:
        h = peek_header(data)
    except ImageHeaderError:
        return  # refused before decoding: always safe
    if h.pixels > FUZZ_LIMIT_PX // 4 or max(h.width, h.height) > 1 << 16:
        return  # refused by AAR_MAX_IMAGE_PIXELS in a real deployment of this size
    kind, w, hh, why = decoder.submit(_decode, data).result(timeout=60)
    assert kind != "limit", f"guard said {h.describe()}, the decoder wanted more: {why}"
    if kind == "ok":
        assert (w, hh) == (h.width, h.height), f"guard said {h.describe()}, decoded {w}x{hh}"
