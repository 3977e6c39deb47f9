"""``serve --foxglove-port``: the service's records live to Foxglove (a tick-loop subscriber).

Every record goes out on the MCAP log's channels (:mod:`app.streams.foxglove_live`); the
stereo pair at most ``image_hz`` times a second, as JPEG. Never blocks the tick thread: the
logger's queue drops what it cannot keep up with.

The SDK's server listens on a loopback port of its own, TLS only with a certificate made at
start (:mod:`app.service.loopback_tls`); ``host:port`` is the gate in front of it
(:mod:`app.service.foxglove_gate`: Host, Origin, token, connection caps).
"""

from __future__ import annotations

import time

from app.geometry.calibration import StereoCalibration
from app.model.frames import RawFrame
from app.model.tick import TickRecord
from app.service.foxglove_gate import FoxgloveGate, GateHealth, GatePolicy
from app.service.loopback_tls import LOOPBACK, make_loopback_tls
from app.service.recording.mcap import mcap_tick, telemetry_schema
from app.sim.rig_mount import default_mount
from app.streams.foxglove_live import FoxgloveLive
from app.streams.mcap_log import FrameInfo, RawPair
from app.types import UInt8Array


class FoxgloveOutput:
    """The Foxglove WebSocket server of the service, its gate and its subscriber."""

    def __init__(
        self,
        host: str,
        port: int,
        calibration: StereoCalibration | None,
        *,
        policy: GatePolicy,
        plant: str | None = None,
        image_hz: float = 5.0,
    ) -> None:
        self.image_period_s = 1.0 / image_hz if image_hz > 0 else float("inf")
        self._last_image = float("-inf")
        tls = make_loopback_tls()
        self.live = FoxgloveLive(
            host=LOOPBACK,
            port=0,
            calibration=calibration,
            telemetry_schema=telemetry_schema(),
            mount=default_mount(plant),
            tls_cert=tls.cert_pem,
            tls_key=tls.key_pem,
        )
        try:
            self.gate = FoxgloveGate(
                host,
                port,
                upstream_port=self.live.port,
                upstream_tls=tls.client_context(),
                policy=policy,
            )
        except BaseException:
            self.live.close()
            raise
        self.port = self.gate.port

    def health(self) -> GateHealth:
        return self.gate.health()

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        """Tick-loop subscriber: the record now, its images at the reduced rate."""
        line = record.model_dump_json().encode()
        self.live.write_tick(mcap_tick(record, line, raw))
        now = time.monotonic()
        if raw is None or now - self._last_image < self.image_period_s:
            return
        frame = raw.stereo_frame  # a stream tick carries its StereoFrame
        left: UInt8Array | None
        right: UInt8Array | None
        if frame is not None:
            left, right = frame.left, frame.right
            info = FrameInfo(frame.seq, frame.t_s, frame.t_left_s, frame.t_right_s)
        else:
            left, right = raw.left_image, raw.right_image
            info = FrameInfo(record.seq, record.t_s)
        if left is None or right is None:
            return
        self._last_image = now
        self.live.write_pair(RawPair(left, right, info), record.seq)

    def close(self) -> None:
        self.gate.close()
        self.live.close()
