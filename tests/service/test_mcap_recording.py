"""Every recording writes one MCAP log (app/service/recording/mcap.py): read back with the
``mcap`` reader and the schemas' own decoders (``mcap-protobuf-support``; json), never our
writer's code. A kill -9 leaves it readable; recovery and ``export-mcap`` rebuild it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from app.cli.main import main as cli_main
from app.resources import load_default_calibration
from app.server.routers import recording as recording_router
from app.service.recording import Recorder
from app.streams.annotations import led_color
from tests.support.mcap_fakes import FakeRaw, fake_record

ROOT = Path(__file__).resolve().parents[2]

TOPICS = {
    "/camera/left/image": "foxglove.CompressedImage",
    "/camera/right/image": "foxglove.CompressedImage",
    "/camera/left/calibration": "foxglove.CameraCalibration",
    "/camera/right/calibration": "foxglove.CameraCalibration",
    "/camera/left/annotations": "foxglove.ImageAnnotations",
    "/camera/right/annotations": "foxglove.ImageAnnotations",
    "/tf": "foxglove.FrameTransforms",
    "/drogue/pose": "foxglove.PoseInFrame",
    "/scene": "foxglove.SceneUpdate",
    "/telemetry": "aar_dock.TickRecord",
}


def read_mcap(path: Path) -> tuple[dict[str, str], list[tuple[str, int, Any]]]:
    """Topics → schema names, and (topic, log time, decoded) in file order."""
    schemas: dict[str, str] = {}
    out: list[tuple[str, int, Any]] = []
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for sch, ch, msg in reader.iter_messages(log_time_order=False):
            schemas[ch.topic] = sch.name if sch is not None else ""
            if ch.message_encoding == "json":
                out.append((ch.topic, msg.log_time, json.loads(msg.data)))
            else:
                out.append((ch.topic, msg.log_time, reader_decode(reader, sch, ch, msg)))
    return schemas, out


_factory = DecoderFactory()


def reader_decode(reader: Any, sch: Any, ch: Any, msg: Any) -> Any:
    fn = _factory.decoder_for(ch.message_encoding, sch)
    assert fn is not None, ch.topic
    return fn(msg.data)


def _record_run(tmp_path: Path, n: int) -> tuple[Recorder, str]:
    rec = Recorder(tmp_path, max_s=60)
    calib = load_default_calibration()
    info = rec.start(frames=True, calibration=calib)
    rng = np.random.default_rng(3)
    for i in range(n):
        rec.on_tick(fake_record(i), FakeRaw(rng))
        time.sleep(0.05)  # the frame writer keeps up (no pair dropped)
    done = rec.stop()
    assert done is not None and done.frame_pairs == n and done.frames_dropped == 0
    assert done.mcap_file == f"{info.id}.mcap" and done.mcap_bytes > 0, done
    return rec, info.id


def test_recording_writes_one_mcap_foxglove_reads(tmp_path: Path) -> None:
    n = 12
    _, rec_id = _record_run(tmp_path, n)
    schemas, msgs = read_mcap(tmp_path / f"{rec_id}.mcap")
    for topic, name in TOPICS.items():
        assert schemas.get(topic) == name, (topic, schemas.get(topic))
    by = {t: [(ns, m) for tt, ns, m in msgs if tt == t] for t in TOPICS}
    # one image per frame per side, bit-exact PNG (the frame folder's very files)
    index = [json.loads(x) for x in (tmp_path / f"{rec_id}.frames/frames.jsonl").open()]
    assert len(index) == n
    for side in ("left", "right"):
        imgs = by[f"/camera/{side}/image"]
        assert len(imgs) == n
        for (_, img), entry in zip(imgs, index, strict=True):
            assert img.format == "png" and img.frame_id == f"camera_{side}"
            assert img.data == (tmp_path / f"{rec_id}.frames" / entry[side]).read_bytes()
        cal = by[f"/camera/{side}/calibration"][0][1]
        c = load_default_calibration()
        k = (c.left if side == "left" else c.right).K
        assert list(cal.K) == pytest.approx(k.ravel().tolist(), abs=0)
        assert list(cal.P) == pytest.approx(np.hstack([k, np.zeros((3, 1))]).ravel().tolist())
        assert cal.distortion_model == "plumb_bob" and len(cal.D) == 5
        assert (cal.width, cal.height) == c.image_size
    # telemetry: exactly the JSONL's records; poses equal the JSONL's to 1e-9 (m)
    tele = [json.loads(x) for x in (tmp_path / f"{rec_id}.jsonl").open()]
    assert [m for _, m in by["/telemetry"]] == tele
    poses = by["/drogue/pose"]
    assert len(poses) == n
    for (_, p), r in zip(poses, tele, strict=True):
        assert p.frame_id == "camera_left"
        got = (p.pose.position.x, p.pose.position.y, p.pose.position.z)
        want = np.asarray(r["pose"]["drogue"]["center_mm"]) / 1e3
        assert np.allclose(got, want, atol=1e-9, rtol=0)
    # the images share their tick's log time; every channel's log times increase
    assert [ns for ns, _ in by["/camera/left/image"]] == [ns for ns, _ in by["/telemetry"]]
    for topic in TOPICS:
        times = [ns for ns, _ in by[topic]]
        assert all(b > a for a, b in zip(times, times[1:], strict=False)), topic
    # log time = first wall time + elapsed t_s (ns since the epoch)
    t0 = by["/telemetry"][0][0]
    assert t0 == round(tele[0]["wall_time"] * 1e9)
    assert by["/telemetry"][-1][0] - t0 == pytest.approx((tele[-1]["t_s"] - tele[0]["t_s"]) * 1e9)
    # annotations: the matched LEDs with their ids, the tracker's windows
    ann = by["/camera/right/annotations"][0][1]
    leds = tele[0]["pose"]["leds"]
    pts = [(a.points[0].x, a.points[0].y) for a in ann.points[: len(leds)]]
    assert pts == [tuple(led["right_px"]) for led in leds]
    assert [t.text for t in ann.texts] == ["1", "2", "3", "4", "5"]
    # each LED in its colour (the page's palette: one producer of the marks)
    for a, led in zip(ann.points, leds, strict=False):
        rgb = tuple(
            round(255 * v) for v in (a.outline_color.r, a.outline_color.g, a.outline_color.b)
        )
        assert rgb == led_color(led["id"])
    assert len(ann.points) == len(leds) + 2  # the LEDs, two windows (4 corners each)
    assert all(len(a.points) == 4 for a in ann.points[len(leds) :])
    # /tf: tanker → drogue, tanker → receiver → camera_left → camera_right
    tf = by["/tf"][0][1]
    edges = {(t.parent_frame_id, t.child_frame_id): t for t in tf.transforms}
    assert set(edges) == {
        ("tanker", "drogue"),
        ("tanker", "receiver"),
        ("receiver", "camera_left"),
        ("camera_left", "camera_right"),
    }
    d = edges[("tanker", "drogue")].translation
    assert (d.x, d.y, d.z) == pytest.approx(tele[0]["drogue_truth_m"])
    base = edges[("camera_left", "camera_right")].translation
    c = load_default_calibration()
    assert np.linalg.norm([base.x, base.y, base.z]) == pytest.approx(c.baseline_mm / 1e3)
    scene = by["/scene"][0][1]
    ids = {e.id for e in scene.entities}
    assert ids == {"drogue_measured", "probe_tip"}
    ring = next(e for e in scene.entities if e.id == "drogue_measured")
    assert len(ring.spheres) == 5 and ring.frame_id == "camera_left"


def test_recording_without_frames_still_writes_its_mcap(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, max_s=60)
    info = rec.start()
    for i in range(5):
        rec.on_tick(fake_record(i), None)
    rec.stop()
    schemas, msgs = read_mcap(tmp_path / f"{info.id}.mcap")
    assert "/camera/left/image" not in schemas
    app = FastAPI()  # the download route
    app.include_router(recording_router.router, prefix="/api/v1")
    app.state.aar = SimpleNamespace(recorder=rec, settings=SimpleNamespace(token=None))
    with TestClient(app) as c:
        r = c.get(f"/api/v1/recordings/{info.id}/recording.mcap")
        assert r.status_code == 200
        assert r.content == (tmp_path / f"{info.id}.mcap").read_bytes()
        assert c.get("/api/v1/recordings/rec-none/recording.mcap").status_code == 404
    assert sum(t == "/telemetry" for t, _, _ in msgs) == 5
    assert sum(t == "/drogue/pose" for t, _, _ in msgs) == 5


def test_the_mcap_telemetry_carries_the_run_time_assurance_and_the_outcome(
    tmp_path: Path,
) -> None:
    """A hand-over to the recovery law (``rta_reason``) and the run's outcome (``run_outcome``,
    last tick) are in ``/telemetry``, read back with the ``mcap`` reader, and its JSON schema
    names both fields."""
    reasons = [None, "break-away: missed the drogue by 0.199 m", "envelope: α 10.2° above 10.0°"]
    rec = Recorder(tmp_path, max_s=60)
    info = rec.start()
    for i in range(6):
        update = {"rta_reason": reasons[min(i, 2)], "run_outcome": "departure" if i == 5 else None}
        rec.on_tick(fake_record(i).model_copy(update=update), None)
    rec.stop()
    with (tmp_path / f"{info.id}.mcap").open("rb") as f:
        got = [
            (sch, json.loads(msg.data))
            for sch, ch, msg in make_reader(f).iter_messages(topics=["/telemetry"])
        ]
    assert [m["rta_reason"] for _, m in got] == [reasons[min(i, 2)] for i in range(6)]
    assert [m["run_outcome"] for _, m in got] == [None] * 5 + ["departure"]
    schema = json.loads(got[0][0].data)
    assert {"rta_reason", "run_outcome"} <= set(schema["properties"])
    assert "departure" in json.dumps(schema["properties"]["run_outcome"])


def test_export_mcap_rebuilds_a_recording_on_disk(tmp_path: Path, capsys: Any) -> None:
    _, rec_id = _record_run(tmp_path, 6)
    live = tmp_path / f"{rec_id}.mcap"
    assert cli_main(["export-mcap", str(tmp_path / f"{rec_id}.jsonl")]) == 2  # exists
    out = tmp_path / "again.mcap"
    assert cli_main(["export-mcap", str(tmp_path / rec_id), "-o", str(out)]) == 0
    assert "6 records, 6 stereo pairs" in capsys.readouterr().out
    a, b = read_mcap(live), read_mcap(out)
    assert a[0] == b[0]
    # the same messages at the same log times; the live file's order across topics is the
    # writer's (images may land after the next tick's telemetry on a loaded machine), the
    # export's is the recording's, so compare them in log-time order
    assert sorted((ns, t) for t, ns, _ in a[1]) == sorted((ns, t) for t, ns, _ in b[1])
    imgs = [m.data for t, _, m in b[1] if t == "/camera/left/image"]
    assert imgs == [m.data for t, _, m in a[1] if t == "/camera/left/image"]
    assert cli_main(["export-mcap", str(tmp_path / "rec-none.jsonl")]) == 2
    assert "no telemetry" in capsys.readouterr().err


WRITER = """
import sys, time
import numpy as np
sys.path.insert(0, {root!r})
from tests.support.mcap_fakes import FakeRaw, fake_record
from app.service.recording import Recorder
from app.server.routers import recording as recording_router
from app.resources import load_default_calibration
rec = Recorder({dir!r}, max_s=600, max_frames_mb=1e6)
info = rec.start(frames=True, calibration=load_default_calibration())
rng = np.random.default_rng(5)
i = 0
while True:
    rec.on_tick(fake_record(i), FakeRaw(rng))
    i += 1
    if i == 40:
        print(info.id, flush=True)
    time.sleep(0.04)
"""


def test_kill_9_leaves_a_readable_mcap_and_recovery_completes_it(tmp_path: Path) -> None:
    code = WRITER.format(root=str(ROOT), dir=str(tmp_path))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT
    )
    try:
        assert proc.stdout is not None
        rec_id = proc.stdout.readline().strip()
        assert rec_id.startswith("rec-"), rec_id
        time.sleep(1.5)  # at least one flush period after the 40th tick
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    path = tmp_path / f"{rec_id}.mcap"
    cut = path.read_bytes()
    # the cut file: the mcap reader streams it up to its last complete chunk
    n_img = n_tele = 0
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        try:
            for r in StreamReader(f, skip_magic=False).records:
                if isinstance(r, Channel):
                    channels[r.id] = r.topic
                if isinstance(r, Message):
                    n_img += channels[r.channel_id] == "/camera/left/image"
                    n_tele += channels[r.channel_id] == "/telemetry"
        except (McapError, EOFError):
            pass  # the torn tail: the chunk being written when it was killed
    assert n_img >= 30 and n_tele >= 30, (n_img, n_tele)
    # the next start rebuilds a complete one from the JSONL and the frames
    rec = Recorder(tmp_path)
    (meta,) = [m for m in rec.recovered if m.id == rec_id]
    assert meta.mcap_file == path.name and "rebuilt" in (meta.mcap_note or "")
    assert path.read_bytes() != cut
    schemas, msgs = read_mcap(path)  # seeking reader: summary, footer
    lines = (tmp_path / f"{rec_id}.jsonl").read_bytes().count(b"\n")
    assert sum(t == "/telemetry" for t, _, _ in msgs) == lines == meta.ticks
    assert sum(t == "/camera/left/image" for t, _, _ in msgs) == meta.frame_pairs >= n_img


@pytest.fixture(scope="module")
def png_pairs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from tests.support.streams_sequence import cached_sequence, write_png_folders

    return write_png_folders(cached_sequence(40), tmp_path_factory.mktemp("media"))


def test_serve_and_track_replay_a_recordings_mcap_to_the_live_results(
    tmp_path: Path, png_pairs: tuple[Path, Path]
) -> None:
    """A video stream recorded with frames; ``serve --source mcap:<id>.mcap`` (switched
    through the API) and ``track --left <id>.mcap`` give the live poses."""
    from tests.support.service_app import service_app
    from tests.support.service_settings import SIM_IDLE, service_settings
    from tests.support.stream_checks import assert_same_pose, history_records
    from tests.support.waiting import wait_until

    source = f"video:{png_pairs[0]},{png_pairs[1]}"
    app = service_app(
        service_settings(tmp_path, **SIM_IDLE, history_s=600.0, source=source, stream_fps=8.0)
    )  # the writer keeps up
    with TestClient(app) as c:
        wait_until(lambda: c.get("/api/v1/stream").json()["frames"] >= 5, 30, "first frames")
        assert c.post("/api/v1/recording/start?frames=true").status_code == 200
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of video")
        info = c.post("/api/v1/recording/stop").json()
        assert info["frames_dropped"] == 0, "the frame writer fell behind: test not valid"
        live = {r["stream"]["frame"]: r for r in history_records(c, "video")}
        mcap = tmp_path / "rec" / info["mcap_file"]
        r = c.put("/api/v1/stream/source", json={"source": f"mcap:{mcap}", "realtime": False})
        assert r.status_code == 200, r.text
        wait_until(lambda: c.get("/api/v1/stream").json()["state"] == "ended", 60, "end of replay")
        served = history_records(c, "video")[len(live) :]
    out = tmp_path / "replay.jsonl"
    assert cli_main(["track", "--left", str(mcap), "--jsonl", str(out), "--no-progress"]) == 0
    rows = [json.loads(x) for x in out.open()]
    assert len(rows) == len(served) == info["frame_pairs"] >= 20
    assert rows[0]["mode"] == "acquired"
    for row, srv in zip(rows, served, strict=True):
        ref = live[row["frame"]]
        assert srv["stream"]["frame"] == row["frame"]
        for other in (row, srv["pose"]):
            assert_same_pose(ref["pose"], other)
