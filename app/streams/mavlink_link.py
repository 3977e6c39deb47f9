"""MAVLink 2 output of the navigation result (``pymavlink``): ``HEARTBEAT`` at 1 Hz, one
``LANDING_TARGET`` per navigation result (the mapping: :mod:`app.streams.landing_target`) and,
when asked, a ``STATUSTEXT`` (:meth:`MavlinkLink.send_status`: the run-time assurance's
hand-overs, :mod:`app.service.mavlink_output`).

The service (``aar-dock serve --mavlink udpout:HOST:PORT``) and ``aar-dock track --mavlink …``
open one :class:`MavlinkLink` and hand it each result. The link is an onboard component of its
own (``MAV_TYPE_ONBOARD_CONTROLLER``, component ``MAV_COMP_ID_ONBOARD_COMPUTER`` by default);
it only sends. A send that fails (network unreachable, a closed port) is counted, logged once
per interval and never raised into the navigation loop.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import unicodedata
from dataclasses import dataclass

from app.streams.landing_target import LandingTarget

log = logging.getLogger(__name__)

# MAVLink 2 for the dialect loaded below (pymavlink reads this when a dialect is set)
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_COMP_ID_ONBOARD_COMPUTER = 191
# MAV_SEVERITY (MAVLink common.xml; RFC 5424's levels)
MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
STATUSTEXT_CHUNK = 50  # bytes of text in one STATUSTEXT
STATUSTEXT_MAX_BYTES = 200  # a longer text is cut here (at most 5 chunks)
# what a ground station's ASCII console cannot show, spelled out (the rest: NFKD, then "?")
_ASCII = str.maketrans(
    {
        "α": "alpha",
        "β": "beta",
        "φ": "phi",
        "θ": "theta",
        "ψ": "psi",
        "Δ": "d",
        "°": " deg",
        "±": "+/-",
        "−": "-",
        "–": "-",
        "—": "-",
        "≤": "<=",
        "≥": ">=",
        "·": ".",
        "…": "...",
    }
)
_SCHEMES = ("udpout:", "udpin:", "udp:", "tcp:", "tcpin:")


def check_url(url: str) -> str:
    """The link address, or a ValueError naming what is expected (``udpout:HOST:PORT``)."""
    if not url.startswith(_SCHEMES):
        raise ValueError(
            f"MAVLink address {url!r}: expected udpout:HOST:PORT (or udpin:/udp:/tcp:/tcpin:)"
        )
    rest = url.split(":", 1)[1]
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"MAVLink address {url!r}: expected HOST:PORT after the scheme")
    return url


@dataclass
class LinkStats:
    """What the link has sent (counters since it opened)."""

    heartbeats: int = 0
    targets: int = 0
    targets_valid: int = 0
    statustexts: int = 0  # texts sent (a chunked one counts once)
    send_errors: int = 0
    last_error: str | None = None


def statustext_chunks(text: str) -> list[bytes]:
    """``text`` as the ``text`` fields of ``STATUSTEXT`` messages: ASCII (Greek letters and
    symbols spelled out, accents dropped, anything else ``?``), one chunk if it fits in 50
    bytes, else 50-byte chunks of its first :data:`STATUSTEXT_MAX_BYTES` bytes, the last one
    shorter — the receiver's end-of-text mark is the null that pads it (an empty chunk
    follows a text of an exact multiple of 50 bytes)."""
    plain = unicodedata.normalize("NFKD", text.translate(_ASCII))
    plain = "".join(ch for ch in plain if not unicodedata.combining(ch))  # é → e
    data = plain.encode("ascii", "replace")
    data = data[:STATUSTEXT_MAX_BYTES]
    if len(data) <= STATUSTEXT_CHUNK:
        return [data]
    chunks = [data[i : i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
    if len(chunks[-1]) == STATUSTEXT_CHUNK:
        chunks.append(b"")
    return chunks


class MavlinkLink:
    """A MAVLink 2 sender: heartbeats on a thread of their own, targets on the caller's."""

    def __init__(
        self,
        url: str,
        *,
        system_id: int = 1,
        component_id: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        heartbeat_hz: float = 1.0,
    ) -> None:
        self.url = check_url(url)
        if not 1 <= system_id <= 255 or not 1 <= component_id <= 255:
            raise ValueError("MAVLink system and component ids are 1..255")
        if not heartbeat_hz > 0:
            raise ValueError("heartbeat_hz must be > 0")
        self.stats = LinkStats()
        self._period_s = 1.0 / heartbeat_hz
        self._lock = threading.Lock()  # one writer at a time on the connection
        self._conn = mavutil.mavlink_connection(
            url, source_system=system_id, source_component=component_id, dialect="common"
        )
        self._stop = threading.Event()
        self._failing: str | None = None  # the last send's error while sends keep failing
        self._status_id = 0  # the id of the last chunked STATUSTEXT (1..65535, then again)
        self._last_log = 0.0
        self._thread = threading.Thread(target=self._beat, name="mavlink-heartbeat", daemon=True)
        self._thread.start()

    @property
    def mavlink_version(self) -> int:
        """2 for MAVLink 2 frames (the protocol this link speaks)."""
        return 2 if float(self._conn.WIRE_PROTOCOL_VERSION) >= 2.0 else 1

    def health(self) -> str | None:
        """Why the link is not working (None: it is): its heartbeat thread ended, or sends
        keep failing (the reason of the last one)."""
        if not self._stop.is_set() and not self._thread.is_alive():
            return "the heartbeat thread stopped"
        if self._failing is not None:
            return f"sending fails: {self._failing}"
        return None

    def _failed(self, what: str, exc: OSError) -> None:
        self.stats.send_errors += 1
        self.stats.last_error = f"{what}: {exc}"
        self._failing = self.stats.last_error
        now = time.monotonic()
        if now - self._last_log > 10.0:  # once per interval, not per message
            self._last_log = now
            log.warning("MAVLink %s to %s failed: %s", what, self.url, exc)

    def _beat(self) -> None:
        while not self._stop.is_set():
            try:
                with self._lock:
                    self._conn.mav.heartbeat_send(
                        MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE
                    )
                self.stats.heartbeats += 1
                self._failing = None
            except OSError as exc:
                self._failed("HEARTBEAT", exc)
            self._stop.wait(self._period_s)

    def send(self, target: LandingTarget) -> None:
        """Send one ``LANDING_TARGET`` (never raises on a network error: counted instead)."""
        try:
            with self._lock:
                self._conn.mav.landing_target_send(
                    target.time_usec,
                    target.target_num,
                    target.frame,
                    target.angle_x,
                    target.angle_y,
                    target.distance,
                    target.size_x,
                    target.size_y,
                    target.x,
                    target.y,
                    target.z,
                    target.q,
                    target.type,
                    target.position_valid,
                )
            self.stats.targets += 1
            self.stats.targets_valid += target.position_valid
            self._failing = None
        except OSError as exc:
            self._failed("LANDING_TARGET", exc)

    def send_status(self, severity: int, text: str) -> None:
        """Send ``text`` as ``STATUSTEXT`` with ``severity`` (``MAV_SEVERITY``): one message
        (``id`` 0) when it fits in 50 bytes, else MAVLink 2 chunks sharing a non-zero ``id``
        (``chunk_seq`` 0, 1, …; :func:`statustext_chunks`). Never raises on a network error."""
        chunks = statustext_chunks(text)
        try:
            with self._lock:
                ident = 0
                if len(chunks) > 1:
                    self._status_id = self._status_id % 65535 + 1
                    ident = self._status_id
                for seq, chunk in enumerate(chunks):
                    self._conn.mav.statustext_send(severity, chunk, ident, seq)
            self.stats.statustexts += 1
            self._failing = None
        except OSError as exc:
            self._failed("STATUSTEXT", exc)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._lock:
            self._conn.close()
