"""``serve --foxglove-port``: the MCAP log's channels live on a Foxglove WebSocket server
(app/service/foxglove_output.py), read with a plain WebSocket client speaking Foxglove's
published protocol (``foxglove.sdk.v1``): advertised topics and schemas, a subscribed
``/telemetry`` message equal to the record, images at the reduced rate."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from typing import Any

import numpy as np
import websockets

from app.model.pose import PoseResult
from app.model.tick import TickRecord
from app.resources import load_default_calibration
from app.service.foxglove_gate import GatePolicy
from app.service.foxglove_output import FoxgloveOutput
from app.service.settings import Settings
from tests.support.raw_frames import RawPair

TOPICS = {
    "/camera/left/image": "foxglove.CompressedImage",
    "/camera/right/image": "foxglove.CompressedImage",
    "/camera/left/calibration": "foxglove.CameraCalibration",
    "/camera/left/annotations": "foxglove.ImageAnnotations",
    "/tf": "foxglove.FrameTransforms",
    "/drogue/pose": "foxglove.PoseInFrame",
    "/scene": "foxglove.SceneUpdate",
    "/telemetry": "aar_dock.TickRecord",
}


class _Raw(RawPair):
    def __init__(self) -> None:
        rng = np.random.default_rng(0)
        self.left_image = rng.integers(0, 256, (64, 80), dtype=np.uint8)
        self.right_image = rng.integers(0, 256, (64, 80), dtype=np.uint8)


def _record(i: int) -> TickRecord:
    return TickRecord(
        seq=i,
        source="sim",
        t_s=0.05 * i,
        clock_s=0.0,
        wall_time=time.time(),
        pose=PoseResult(lock=False),
    )


async def _client(port: int, out: FoxgloveOutput) -> tuple[dict[str, str], list[Any], int]:
    url = f"ws://127.0.0.1:{port}"
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[str, dict[str, Any]] = {}
        deadline = time.monotonic() + 10
        while not all(t in channels for t in TOPICS) and time.monotonic() < deadline:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg.get("op") == "advertise":
                for ch in msg["channels"]:
                    channels[ch["topic"]] = ch
        subs = [
            {"id": 1, "channelId": channels["/telemetry"]["id"]},
            {"id": 2, "channelId": channels["/camera/left/image"]["id"]},
        ]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        await asyncio.sleep(0.5)
        tele: list[Any] = []
        images = 0
        for i in range(30):  # 1.5 s of ticks at 20 Hz; images at 2 Hz
            out.on_tick(_record(i), _Raw())
            await asyncio.sleep(0.05)
        end = time.monotonic() + 2
        while time.monotonic() < end:
            try:
                data = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(data, bytes) and data[0] == 1:  # message data
                sub = struct.unpack_from("<I", data, 1)[0]
                if sub == 1:
                    tele.append(json.loads(data[13:]))
                elif sub == 2:
                    images += 1
        return {t: c["schemaName"] for t, c in channels.items()}, tele, images


def test_live_foxglove_channels_on_loopback() -> None:
    policy = GatePolicy.from_settings(Settings(_env_file=None))  # type: ignore[call-arg]
    out = FoxgloveOutput("127.0.0.1", 0, load_default_calibration(), policy=policy, image_hz=2.0)
    try:
        assert out.port > 0
        schemas, tele, images = asyncio.run(_client(out.port, out))
    finally:
        out.close()
    for topic, name in TOPICS.items():
        assert schemas.get(topic) == name, topic
    assert [r["seq"] for r in tele] == list(range(30))
    assert tele[3] == json.loads(_record(3).model_dump_json()) | {"wall_time": tele[3]["wall_time"]}
    assert 2 <= images <= 5  # the reduced rate: 2 Hz over ≈ 1.5 s, not 30


def test_live_foxglove_is_off_by_default_and_loopback() -> None:
    s = Settings(_env_file=None)  # type: ignore[call-arg]
    assert s.foxglove_port is None and s.foxglove_host == "127.0.0.1"
