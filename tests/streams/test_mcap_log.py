"""MCAP logs of offline runs and their replay (app/streams/mcap_log/, mcap_source.py):
``track --mcap`` then ``track --left OUT.mcap`` gives the same poses; the images read back
with the ``mcap`` reader and Foxglove's protobuf schemas are the pixels tracked; a corrupt
file is one line and exit 2, a truncated one replays up to its last complete chunk."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from app.cli.main import main as cli_main
from app.streams.frames import SourceError
from app.streams.mcap_log import ExposureClock
from app.streams.sources import SourceOptions, open_source, parse_source
from tests.support.streams_sequence import cached_sequence, read_jsonl, write_png_folders

N = 10


def _without_timings(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k != "timing_ms"} for r in rows]


@pytest.fixture(scope="module")
def tracked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path, Path]:
    d = tmp_path_factory.mktemp("mcap")
    left, right = write_png_folders(cached_sequence(N), d)
    out, mcap = d / "live.jsonl", d / "run.mcap"
    args = ["track", "--left", str(left), "--right", str(right), "--jsonl", str(out)]
    assert cli_main([*args, "--mcap", str(mcap), "--no-progress"]) == 0
    return d, left, out, mcap


def test_track_mcap_holds_the_tracked_pixels_and_poses(tracked: tuple[Path, ...]) -> None:
    d, left_dir, out, mcap = tracked
    rows = read_jsonl(out)
    images, poses, tele, times = [], [], [], []
    with mcap.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for sch, ch, msg, dec in reader.iter_decoded_messages(
            topics=["/camera/left/image", "/drogue/pose"]
        ):
            if ch.topic == "/camera/left/image":
                assert sch.name == "foxglove.CompressedImage" and dec.format == "png"
                images.append(cv2.imdecode(np.frombuffer(dec.data, np.uint8), -1))
                times.append(msg.log_time)
            else:
                poses.append(dec.pose.position)
        for sch, _, msg in reader.iter_messages(topics=["/telemetry"]):
            assert sch.name == "aar_dock.TrackRow" and sch.encoding == "jsonschema"
            tele.append(json.loads(msg.data))
    files = sorted(left_dir.glob("*.png"))
    assert len(images) == len(files) == N
    for img, path in zip(images, files, strict=True):  # lossless: the very pixels
        assert np.array_equal(img, cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
    assert tele == rows
    locked = [r for r in rows if r["lock"]]
    assert len(poses) == len(locked)
    for p, r in zip(poses, locked, strict=True):
        want = np.asarray(r["drogue"]["center_mm"]) / 1e3
        assert np.allclose([p.x, p.y, p.z], want, atol=1e-9, rtol=0)
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    assert times[-1] - times[0] == pytest.approx((rows[-1]["t_s"] - rows[0]["t_s"]) * 1e9)


def test_track_replays_an_mcap_to_the_same_poses(tracked: tuple[Path, ...]) -> None:
    d, _, out, mcap = tracked
    again = d / "replay.jsonl"
    assert cli_main(["track", "--left", str(mcap), "--jsonl", str(again), "--no-progress"]) == 0
    assert _without_timings(read_jsonl(again)) == _without_timings(read_jsonl(out))


def test_truncated_mcap_replays_up_to_its_last_complete_chunk(
    tracked: tuple[Path, ...], tmp_path: Path
) -> None:
    _, _, out, mcap = tracked
    data = mcap.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    rows = tmp_path / "cut.jsonl"
    assert cli_main(["track", "--left", str(cut), "--jsonl", str(rows), "--no-progress"]) == 0
    got = _without_timings(read_jsonl(rows))
    assert 0 < len(got) < N
    assert got == _without_timings(read_jsonl(out))[: len(got)]


def test_corrupt_mcap_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all" * 10)
    assert cli_main(["track", "--left", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a readable MCAP" in err and "Traceback" not in err
    assert cli_main(["track", "--left", str(tmp_path / "none.mcap")]) == 2
    assert "no such MCAP file" in capsys.readouterr().err


def test_mcap_source_spec(tracked: tuple[Path, ...], tmp_path: Path) -> None:
    _, _, _, mcap = tracked
    spec = parse_source(f"mcap:{mcap}")
    assert spec.kind == "video" and spec.left == str(mcap) and not spec.right
    src = open_source(spec, SourceOptions(realtime=False))
    try:
        frame = src.read()
        assert frame is not None and frame.seq == 0 and src.calibration is not None
    finally:
        src.close()
    with pytest.raises(SourceError, match="no such MCAP"):
        open_source(f"mcap:{tmp_path / 'none.mcap'}")
    with pytest.raises(SourceError, match="one MCAP file"):
        parse_source("mcap:a.mcap,b.mcap")


def test_exposure_clock_maps_source_time_onto_the_epoch_increasing() -> None:
    c = ExposureClock()
    assert c.to_ns(5.0, 1000.0) == 1000 * 10**9
    assert c.to_ns(5.5, 1000.001) == 1000 * 10**9 + 500_000_000  # source time, not wall time
    # a reset (t_s back to 0) re-anchors on the wall time, never going back
    assert c.to_ns(0.0, 1000.2) == 1000 * 10**9 + 500_000_001
    assert c.to_ns(0.0, 1003.0) == 1003 * 10**9  # t_s not advancing (uploads): wall time


def test_serve_refuses_a_corrupt_mcap_source_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 64)  # the magic, then garbage
    assert cli_main(["serve", "--source", f"mcap:{bad}", "--no-viser"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("aar-dock serve: --source:") and err.count("\n") == 1
    assert "Traceback" not in err


def test_loggers_left_open_are_finished_at_interpreter_exit(tmp_path: Path) -> None:
    """A process that leaves an MCAP writer and a live Foxglove server open exits cleanly
    (status 0, no Fatal Python error from foxglove-sdk's native threads) and the MCAP is
    finished: its summary (statistics) is written, readable by the ``mcap`` reader."""
    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "open.mcap"
    script = f"""
from app.model.tick import TickRecord
from app.streams.foxglove_live import FoxgloveLive
from app.streams.mcap_log import McapLogWriter
schema = TickRecord.model_json_schema()
w = McapLogWriter({str(out)!r}, calibration=None, telemetry_schema=schema)
live = FoxgloveLive(host="127.0.0.1", port=0, calibration=None, telemetry_schema=schema)
print("left open")
"""
    proc = subprocess.run(
        [sys.executable, "-c", script],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Fatal Python error" not in proc.stderr
    with out.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
