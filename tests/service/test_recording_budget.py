"""Recording duration you can plan on (issue 33 item 4): ``GET /recording`` says the write rate
and the time left during a recording and how long one can run before it starts; the default
options hold 10 minutes of frames at 30 Hz within the default budget; every codec's files
replay; a frame recording stops at the free-space floor."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from app.cli.main import main as cli_main
from app.service.recording import Recorder
from app.service.recording.budget import Limits, Rates, Written, time_left
from app.service.settings import Settings
from app.streams.frame_log import read_index
from tests.support.service_app import service_app
from tests.support.service_settings import SIM_IDLE, service_settings
from tests.support.stream_checks import assert_same_pose, history_records
from tests.support.waiting import wait_until

TEN_MIN_S = 600.0
DRIVEN_HZ = 30.0


def test_time_left_is_the_first_bound_at_the_rates() -> None:
    limits = Limits(
        max_s=900.0,
        max_frames_bytes=24_000_000_000,
        max_telemetry_bytes=200_000_000,
        floor_bytes=512_000_000,
        free_bytes=50_000_000_000,
    )
    written = Written(telemetry=1_000_000, frames=3_000_000_000, mcap=3_000_000_000)
    rates = Rates(telemetry_bps=60_000.0, frames_bps=30e6, mcap_bps=30e6)
    # by hand: frames (24e9 - 3e9) / 30e6 = 700 s; free (50e9 - 0.512e9) / 60.06e6 = 824 s;
    # telemetry (200e6 - 1e6) / 6e4 = 3317 s; max_s 900 - 100 = 800 s
    assert time_left(100.0, written, rates, limits, frames=True) == (700.0, "frames budget")
    small_disk = Limits(900.0, 24_000_000_000, 200_000_000, 512_000_000, 10_000_000_000)
    s, bound = time_left(100.0, written, rates, small_disk, frames=True)
    assert bound == "free space" and s == pytest.approx((10e9 - 0.512e9) / 60.06e6)
    # without frames neither the frames' budget nor the free-space floor applies
    s, bound = time_left(100.0, Written(telemetry=1_000_000), rates, small_disk, frames=False)
    assert (s, bound) == (800.0, "max_s")


def test_time_left_during_a_default_frame_recording_and_ten_minutes_fit(tmp_path: Path) -> None:
    """The default simulated stream (1280×1024 frames), the default options: the estimate
    before the start, the measured rate and the time left during it; the measured bytes of a
    pair, driven at 30 Hz, fit 10 minutes in the default bounds."""
    settings = service_settings(tmp_path)
    defaults = Settings()
    with TestClient(service_app(settings)) as c:
        wait_until(lambda: c.get("/api/v1/healthz").json()["ticks"] >= 10, 60, "first ticks")
        got: list[dict] = []

        def estimated() -> bool:
            got.append(c.get("/api/v1/recording").json())
            return got[-1]["time_left_s"] is not None

        wait_until(estimated, 30, "an estimate before the start", poll_s=0.5)
        before = got[-1]
        assert before["active"] is False and before["frames"] and before["lossless"]
        assert "1280×1024" in before["basis"] and before["pair_bytes"] > 100_000
        assert 0 < before["time_left_s"] <= defaults.recording_max_s
        r = c.post("/api/v1/recording/start?frames=true")
        assert r.status_code == 200, r.text
        assert r.json()["frames_encoding"] == "png-huffman"
        time.sleep(3.0)
        during = c.get("/api/v1/recording").json()
        info = c.post("/api/v1/recording/stop").json()
    assert during["active"] and during["id"] == info["id"] and during["elapsed_s"] >= 2.5
    assert during["rate_bytes_per_s"] > 0 and during["limited_by"] is not None
    # the rate is the bytes written over the recording, and the time left the first bound
    total = during["telemetry_bytes"] + during["frames_bytes"] + during["mcap_bytes"]
    assert during["rate_bytes_per_s"] == pytest.approx(total / during["elapsed_s"])
    assert during["mb_per_min"] == pytest.approx(during["rate_bytes_per_s"] * 60 / 1e6)
    frames_left = (during["max_frames_mb"] * 1e6 - during["frames_bytes"]) / during[
        "frames_bytes_per_s"
    ]
    assert 0 < during["time_left_s"] <= min(frames_left, during["max_s"] - during["elapsed_s"])
    # 10 minutes at 30 Hz with this stream's real pairs, within the default bounds
    assert info["frame_pairs"] >= 10  # pairs dropped by a busy machine do not change their size
    pair_bytes = info["frames_bytes"] / info["frame_pairs"]
    line_bytes = info["telemetry_bytes"] / info["ticks"]
    ten_min = TEN_MIN_S * DRIVEN_HZ
    print(f"pair {pair_bytes / 1e6:.3f} MB: {pair_bytes * DRIVEN_HZ * 60 / 1e6:.0f} MB/min")
    assert defaults.recording_max_s >= TEN_MIN_S
    assert pair_bytes * ten_min < defaults.recording_frames_max_mb * 1e6
    assert line_bytes * ten_min < defaults.recording_max_mb * 1e6


@pytest.fixture(scope="module")
def png_pairs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from tests.support.streams_sequence import cached_sequence, write_png_folders

    return write_png_folders(cached_sequence(40), tmp_path_factory.mktemp("media"))


@pytest.mark.parametrize(
    ("query", "label", "ext", "fps"),
    [
        ("", "png-huffman", ".png", 8.0),
        ("&codec=png&png_level=3", "png level 3", ".png", 4.0),  # slower to encode
        ("&codec=jpeg&jpeg_quality=90", "jpeg q90 (lossy)", ".jpg", 8.0),
    ],
)
def test_each_codec_records_files_that_replay(
    tmp_path: Path, png_pairs: tuple[Path, Path], query: str, label: str, ext: str, fps: float
) -> None:
    """A video stream recorded with each codec: the frames hold the codec's files (the
    lossless ones every source pixel), and ``track --left REC.frames`` / ``REC.mcap`` replay
    every pair — to the live poses with a lossless codec."""
    source = f"video:{png_pairs[0]},{png_pairs[1]}"
    app = service_app(
        service_settings(tmp_path, **SIM_IDLE, history_s=600.0, source=source, stream_fps=fps)
    )  # the writer keeps up: every pair recorded
    with TestClient(app) as c:
        wait_until(lambda: c.get("/api/v1/stream").json()["frames"] >= 3, 30, "first frames")
        r = c.post(f"/api/v1/recording/start?frames=true{query}")
        assert r.status_code == 200, r.text
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of video")
        info = c.post("/api/v1/recording/stop").json()
        live = {rec["stream"]["frame"]: rec for rec in history_records(c, "video")}
    assert info["frames_encoding"] == label and info["frames_dropped"] == 0
    rec = tmp_path / "rec"
    frames = rec / info["frames_dir"]
    entries = read_index(frames)
    assert len(entries) == info["frame_pairs"] >= 20
    assert all(e["left"].endswith(ext) and e["right"].endswith(ext) for e in entries)
    sources = sorted(png_pairs[0].iterdir())
    if ext == ".png":  # lossless: the recorded pixels are the source's (Pillow decodes both)
        for e in entries[:3]:
            got = np.asarray(Image.open(frames / e["left"]))
            want = np.asarray(Image.open(sources[e["seq"]]).convert("L"))
            assert np.array_equal(got, want), e
    for path in (frames, rec / info["mcap_file"]):
        out = tmp_path / f"{path.suffix}.jsonl"
        assert cli_main(["track", "--left", str(path), "--jsonl", str(out), "--no-progress"]) == 0
        rows = [json.loads(x) for x in out.open()]
        assert len(rows) == len(entries)
        if ext == ".png":
            for row in rows:
                assert_same_pose(live[row["frame"]]["pose"], row)
        else:  # lossy: a replay that still locks on most pairs
            assert sum(row["lock"] for row in rows) >= 0.8 * len(rows)


def test_bad_codec_options_get_422(tmp_path: Path) -> None:
    with TestClient(service_app(service_settings(tmp_path, **SIM_IDLE))) as c:
        for q in ("codec=webp", "png_level=0", "jpeg_quality=101"):
            for method, url in (("GET", "/api/v1/recording"), ("POST", "/api/v1/recording/start")):
                r = c.request(method, f"{url}?frames=true&{q}")
                assert r.status_code == 422, (method, q, r.text)
        assert c.get("/api/v1/recording").json()["active"] is False


def test_a_frame_recording_stops_at_the_free_space_floor(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The floor is kept while the recording runs, not only at its start."""
    import app.service.recording.recorder as recorder_module

    free = {"mb": 5000.0}
    monkeypatch.setattr(recorder_module, "free_mb", lambda _d: free["mb"])
    rec = Recorder(tmp_path, min_free_mb=1000.0, mcap=False)
    info = rec.start(frames=True)
    free["mb"] = 900.0  # the disk fills (other writers, or this recording)
    wait_until(lambda: rec.active is None, 10, "the recording stops at the floor")
    done = rec.get(info.id)
    assert done is not None and done.status == "complete"
    assert "floor" in (done.stop_reason or "") and "1000" in (done.stop_reason or "")
