"""Frame sources, pairing, push protocol, frame recordings and stream guidance (no server)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.model.frames import StereoFrame
from app.model.pose import DrogueResult, PoseResult
from app.streams.frame_log import FrameRecordingSource, FrameRecordingWriter, read_index
from app.streams.frames import EndOfStream, SourceError
from app.streams.guidance import StreamGuidance, StreamGuidanceConfig
from app.streams.protocol import ProtocolError, decode_message, encode_message
from app.streams.sources import (
    CameraSource,
    PushSource,
    SourceOptions,
    VideoSource,
    open_source,
    parse_source,
)


def _img(value: int, shape: tuple[int, int] = (24, 32)) -> np.ndarray:
    img = np.zeros(shape, np.uint8)
    img[2:6, 2 + value % 20] = 200  # a mark that identifies the frame
    img[0, 0] = value
    return img


def _folder(d: Path, times: list[float], base: int) -> Path:
    d.mkdir()
    for i, _ in enumerate(times):
        cv2.imwrite(str(d / f"{i:03d}.png"), _img(base + i))
    (d / "timestamps.txt").write_text("\n".join(str(t) for t in times))
    return d


def test_parse_source_specs() -> None:
    assert parse_source("sim").kind is None
    assert parse_source("push").kind == "push"
    s = parse_source("video:a.avi,b.avi")
    assert (s.kind, s.left, s.right, s.text) == ("video", "a.avi", "b.avi", "video:a.avi,b.avi")
    s = parse_source("camera:0")
    assert (s.kind, s.left, s.right) == ("camera", "0", "")
    assert parse_source("camera:/dev/video2,/dev/video3").right == "/dev/video3"
    for bad in (
        "rtsp:x",
        "video:",
        "video:a,",
        "camera:1,2,3",
        "nonsense",
        "camera:/etc/passwd",  # a file is not a camera (it would bypass AAR_STREAM_ROOTS)
        "camera:0,/tmp/x.png",
        "camera:/dev/video0/../../tmp/x.png",
        "camera:../x.avi",
    ):
        with pytest.raises(SourceError):
            parse_source(bad)
    with pytest.raises(SourceError, match="frame recording"):
        open_source("video:/nonexistent-dir")
    with pytest.raises(SourceError, match="no such video file"):
        open_source("video:/nonexistent/l.avi,/nonexistent/r.avi")


def test_pairing_by_timestamps_drops_and_counts_skewed_frames(tmp_path: Path) -> None:
    # right camera: frame 2 is 25 ms late (no partner within 10 ms), and an extra frame
    # at 0.05 s that the left camera does not have
    lt = [0.0, 0.1, 0.2, 0.3, 0.4]
    rt = [0.002, 0.05, 0.101, 0.225, 0.299, 0.404]
    left = _folder(tmp_path / "l", lt, 0)
    right = _folder(tmp_path / "r", rt, 100)
    src = VideoSource(str(left), str(right), SourceOptions(realtime=False, max_skew_s=0.010))
    pairs = []
    with pytest.raises(EndOfStream):
        while True:
            f = src.read()
            assert f is not None
            pairs.append((int(f.left[0, 0]), int(f.right[0, 0]), f.skew_s))
    # left 0↔right 0, left 1↔right 2, left 3↔right 4, left 4↔right 5; dropped: right 1,
    # left 2, right 3
    assert [(a, b) for a, b, _ in pairs] == [(0, 100), (1, 102), (3, 104), (4, 105)]
    assert all(s <= 0.010 for _, _, s in pairs)
    assert src.stats.dropped_skew == 3
    assert src.stats.pairs == 4
    assert src.stats.max_skew_ms == pytest.approx(4.0, abs=1e-6)
    # the same inputs as globs (timestamps.txt is beside the images, not in the glob: index/fps)
    globbed = VideoSource(
        str(left / "*.png"), str(right / "00[0-4].png"), SourceOptions(realtime=False, fps=10)
    )
    first = globbed.read()
    assert first is not None and (int(first.left[0, 0]), int(first.right[0, 0])) == (0, 100)


def test_video_loop_keeps_time_and_frame_numbers_increasing(tmp_path: Path) -> None:
    left = _folder(tmp_path / "l", [0.0, 0.1, 0.2], 0)
    right = _folder(tmp_path / "r", [0.0, 0.1, 0.2], 50)
    src = VideoSource(str(left), str(right), SourceOptions(realtime=False, loop=True, fps=10.0))
    frames = [src.read() for _ in range(7)]
    seqs = [f.seq for f in frames if f is not None]
    times = [f.t_s for f in frames if f is not None]
    assert seqs == list(range(7))
    assert times == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert [int(f.left[0, 0]) for f in frames if f is not None] == [0, 1, 2, 0, 1, 2, 0]


def test_realtime_pacing_follows_the_frame_times(tmp_path: Path) -> None:
    times = [i * 0.02 for i in range(8)]  # 50 fps: 0.14 s from first to last
    left = _folder(tmp_path / "l", times, 0)
    right = _folder(tmp_path / "r", times, 0)
    paced = VideoSource(str(left), str(right), SourceOptions(realtime=True))
    t0 = time.perf_counter()
    for _ in times:
        paced.read()
    paced_s = time.perf_counter() - t0
    fast = VideoSource(str(left), str(right), SourceOptions(realtime=False))
    t0 = time.perf_counter()
    for _ in times:
        fast.read()
    fast_s = time.perf_counter() - t0
    assert paced_s >= 0.13
    assert fast_s < paced_s


def _avi(path: Path, frames: list[np.ndarray]) -> Path:
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h), False)
    assert vw.isOpened()
    for f in frames:
        vw.write(f)
    vw.release()
    return path


def test_camera_source_on_video_files_two_devices_and_side_by_side(tmp_path: Path) -> None:
    """``VideoCapture`` on files stands in for devices (no camera in CI)."""
    rng = np.random.default_rng(0)
    lefts = [rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(5)]
    rights = [rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(5)]
    l_avi = _avi(tmp_path / "l.avi", lefts)
    r_avi = _avi(tmp_path / "r.avi", rights)
    sbs = _avi(
        tmp_path / "sbs.avi", [np.hstack([a, b]) for a, b in zip(lefts, rights, strict=True)]
    )

    # the files' own decoded frames, for comparison
    def decoded(path: Path) -> list[np.ndarray]:
        cap = cv2.VideoCapture(str(path))
        out = []
        while True:
            ok, f = cap.read()
            if not ok:
                return out
            out.append(f[:, :, 0])

    two = CameraSource(
        str(l_avi), str(r_avi), SourceOptions(max_skew_s=0.5)
    )  # the spec refuses files
    assert isinstance(two, CameraSource)
    got = []
    with pytest.raises(EndOfStream):
        while True:
            f = two.read()
            assert f is not None
            got.append(f)
    assert [f.seq for f in got] == list(range(5))
    assert all(f.t_left_s is not None and f.skew_s < 0.5 for f in got)
    for f, dl, dr in zip(got, decoded(l_avi), decoded(r_avi), strict=True):
        assert np.array_equal(f.left, dl) and np.array_equal(f.right, dr)
    split = CameraSource(str(sbs))
    whole = decoded(sbs)
    for k in range(5):
        f = split.read()
        assert f is not None and f.left.shape == (48, 64) and f.right.shape == (48, 64)
        assert np.array_equal(f.left, whole[k][:, :64])
        assert np.array_equal(f.right, whole[k][:, 64:])
        assert f.skew_s == 0.0
    with pytest.raises(EndOfStream):
        split.read()


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img)[1].tobytes()


def test_push_protocol_round_trip_and_refusals() -> None:
    left, right = _png(_img(1)), _png(_img(2))
    data = encode_message(left, right, t_s=1.25, seq=7, exposure_ms=2.0, t_left_s=1.249)
    msg = decode_message(data)
    assert (msg.t_s, msg.seq, msg.exposure_ms, msg.t_left_s, msg.t_right_s) == (
        1.25,
        7,
        2.0,
        1.249,
        None,
    )
    assert msg.left == left and msg.right == right
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        decode_message(data, max_bytes=len(data) - 1)
    with pytest.raises(ProtocolError, match="magic"):
        decode_message(b"XXXX" + data[4:])
    with pytest.raises(ProtocolError, match="message length"):
        decode_message(data + b"\0")
    with pytest.raises(ProtocolError, match="prefix"):
        decode_message(b"AARP")
    hdr = json.dumps({"t_s": "soon", "seq": 1, "left_bytes": 1, "right_bytes": 1}).encode()
    bad = b"AARP" + (1).to_bytes(2, "little") + len(hdr).to_bytes(4, "little") + hdr + b"ab"
    with pytest.raises(ProtocolError, match="t_s"):
        decode_message(bad)


def test_push_source_keeps_the_newest_pair_and_counts_drops() -> None:
    src = PushSource(SourceOptions(max_skew_s=0.005))
    for seq in range(4):
        src.put(decode_message(encode_message(_png(_img(seq)), _png(_img(seq)), t_s=seq, seq=seq)))
    frame = src.read(timeout_s=0.1)
    assert frame is not None and frame.seq == 3 and int(frame.left[0, 0]) == 3
    assert src.stats.dropped_backpressure == 3
    assert src.read(timeout_s=0.05) is None  # nothing new
    src.put(decode_message(encode_message(b"not an image", _png(_img(0)), t_s=9, seq=9)))
    assert src.read(timeout_s=0.1) is None
    assert src.stats.rejected == 1 and "undecodable" in (src.last_error or "")
    src.put(
        decode_message(
            encode_message(
                _png(_img(0)), _png(_img(0)), t_s=1, seq=10, t_left_s=1.0, t_right_s=1.02
            )
        )
    )
    assert src.read(timeout_s=0.1) is None  # 20 ms skew > 5 ms
    assert src.stats.dropped_skew == 1
    src.close()
    with pytest.raises(EndOfStream):
        src.read(timeout_s=0.1)


def test_frame_recording_is_crash_safe_and_bounded(tmp_path: Path) -> None:
    rec = FrameRecordingWriter(tmp_path / "a.frames", None, max_bytes=10**9)
    for i in range(5):
        assert rec.submit(StereoFrame(_img(i), _img(i + 50), t_s=0.1 * i, seq=i), record_seq=i)
    meta = rec.close()
    assert meta["status"] == "complete" and meta["pairs"] == 5
    # a crash mid-pair: a torn index line and a pair whose right image never landed
    d = tmp_path / "a.frames"
    with open(d / "frames.jsonl", "ab") as f:
        f.write(b'{"i": 5, "seq": 5, "t_s"')
    (d / "right" / "000004.png").unlink()
    entries = read_index(d)
    assert [e["seq"] for e in entries] == [0, 1, 2, 3]
    src = FrameRecordingSource(d)
    got = [src.read() for _ in range(4)]
    assert [int(f.left[0, 0]) for f in got if f is not None] == [0, 1, 2, 3]
    assert np.array_equal(got[2].right, _img(52))  # lossless
    with pytest.raises(EndOfStream):
        src.read()
    small = FrameRecordingWriter(tmp_path / "b.frames", None, max_bytes=300)
    for i in range(4):
        small.submit(StereoFrame(_img(i), _img(i), t_s=i, seq=i))
    meta = small.close()
    assert meta["stop_reason"].startswith("reached") and meta["pairs"] < 4
    assert meta["bytes"] <= 300


def _pose(center_mm: np.ndarray) -> PoseResult:
    return PoseResult(
        lock=True,
        drogue=DrogueResult(
            center_mm=tuple(center_mm), normal=(0.0, 0.0, -1.0), radius_mm=75.0, rms_mm=0.0
        ),
    )


def test_stream_guidance_against_constant_velocity_kinematics() -> None:
    """Closing at 1.2 m/s with a lateral drift: closure speed, time to contact and the
    predicted miss converge to the straight-line answers."""
    tip_mm = np.array([0.0, 100.0, 300.0])  # probe tip below and ahead of the left camera
    g = StreamGuidance(StreamGuidanceConfig(probe_tip_cam_mm=tuple(tip_mm)))
    p0 = np.array([50.0, 80.0, 3000.0])  # camera frame, mm
    v = np.array([30.0, -10.0, -1200.0])  # mm/s: right, up, closing
    dt = 1 / 30
    out = None
    for k in range(60):
        out = g.update(k * dt, _pose(p0 + v * k * dt))
    assert out is not None
    p = p0 + v * 59 * dt
    rel = (p - tip_mm) / 1e3  # camera axes, m
    gap, lat_x, lat_y = rel[2], rel[0], rel[1]
    assert out.closure_speed_mps == pytest.approx(1.2, abs=0.01)
    assert out.rel_position_m == pytest.approx((gap, lat_x, lat_y), abs=2e-3)
    t_go = gap / 1.2
    assert out.time_to_contact_s == pytest.approx(t_go, rel=0.01)
    miss = np.hypot(lat_x + t_go * v[0] / 1e3, lat_y + t_go * v[1] / 1e3)
    assert out.predicted_miss_m == pytest.approx(miss, abs=3e-3)
    # no lock: the estimate coasts, then is withheld
    for k in range(60, 60 + 20):
        out = g.update(k * dt, PoseResult(lock=False, reason="no blobs"))
    assert out.drogue_measured_m is None and out.drogue_estimate_m is None
    assert out.coast_s > 0.5


def test_a_frame_of_the_wrong_size_is_no_lock_with_the_reason() -> None:
    from app.geometry.calibration import paper_calibration
    from app.streams.processor import StreamProcessor

    proc = StreamProcessor(paper_calibration())
    tick = proc.process(StereoFrame(_img(1), _img(1), t_s=0.0, seq=0))
    assert not tick.lock and tick.mode == "error"
    assert "bad frame" in (tick.lock_reason or "") and "1280" in (tick.lock_reason or "")
    assert tick.guidance.drogue_estimate_m is None


def test_a_missing_camera_device_is_a_source_error() -> None:
    t0 = time.perf_counter()
    with pytest.raises(SourceError, match="cannot open"):
        open_source("camera:97,98")
    assert time.perf_counter() - t0 < 10
