"""Live Foxglove: the MCAP log's channels (:mod:`app.streams.mcap_log`) on a Foxglove
WebSocket server (``foxglove-sdk``'s ``start_server``), for Foxglove's *Open connection*.

Same topics, schemas, frames and log times as the MCAP log; the images are JPEG (the
adapter hands over a pair at a reduced rate), encoded by the logger's thread. The SDK's server
checks no Origin or token: the service puts it on loopback, TLS only (``tls_cert``,
``tls_key``), behind its own gate (``app/service/foxglove_gate.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

from foxglove import Context

from app.geometry.calibration import StereoCalibration
from app.streams.mcap_log import FoxgloveLogger

if TYPE_CHECKING:
    from app.model.mount import CameraMount

log = logging.getLogger(__name__)


class FoxgloveLive(FoxgloveLogger):
    """A Foxglove WebSocket server on ``host:port`` (port 0: a free one, see :attr:`port`);
    with ``tls_cert`` and ``tls_key`` (PEM, the key PKCS#8) it speaks ``wss://`` only."""

    def __init__(
        self,
        *,
        host: str,
        port: int,
        calibration: StereoCalibration | None,
        telemetry_schema: Mapping[str, object],
        mount: CameraMount | None = None,
        jpeg_quality: int = 80,
        queue_items: int = 32,
        tls_cert: bytes | None = None,
        tls_key: bytes | None = None,
    ) -> None:
        import foxglove

        ctx = Context()
        super().__init__(
            ctx,
            name=f"foxglove-ws:{host}:{port}",
            calibration=calibration,
            telemetry_schema=telemetry_schema,
            mount=mount,
            threaded=True,
            queue_items=queue_items,
            image_format="jpeg",
            jpeg_quality=jpeg_quality,
        )
        try:
            self._server = foxglove.start_server(
                name="aar-dock",
                host=host,
                port=port,
                context=ctx,
                tls_cert=tls_cert,  # PEM; with the key (PKCS#8): wss:// only
                tls_key=tls_key,
            )
        except Exception:
            self.close()
            raise
        self.host = host
        self.port = int(self._server.port)

    def _finish(self) -> None:
        server = getattr(self, "_server", None)
        if server is not None:
            server.stop()
