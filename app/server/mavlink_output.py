"""The navigation stream as MAVLink 2 (``aar-dock serve --mavlink udpout:HOST:PORT``): a tick-loop
subscriber that turns each published navigation record into one ``LANDING_TARGET``
(:mod:`app.streams.landing_target`) sent by :class:`app.streams.mavlink_link.MavlinkLink`.

Records of the simulated stream and of camera/video/push streams are sent; uploads are not
(a one-off pair is not the navigation stream). ``time_usec`` is the frame's exposure time on the
source's clock: the stream's capture time, the simulation's time for simulated ticks.

The run-time assurance's hand-overs (the record's ``rta_reason``) are ``STATUSTEXT`` messages,
once per hand-over: when the recovery law takes over (``rta_reason`` from None to a reason, or
to another reason), ``MAV_SEVERITY_CRITICAL`` for an envelope recovery (``envelope: …``) and
``MAV_SEVERITY_WARNING`` for a break-away, the text ``RTA <reason>``; when it hands back
(``rta_reason`` back to None, or a record of another run or source), ``MAV_SEVERITY_NOTICE``,
``RTA off: normal control``. ``LANDING_TARGET`` is unchanged meanwhile (the vision fix stays
valid while the recovery law flies).
"""

from __future__ import annotations

from app.server import mcap_recording
from app.server.schemas import TickRecord
from app.streams.frames import RawFrame
from app.streams.landing_target import RigMount, landing_target
from app.streams.mavlink_link import (
    MAV_SEVERITY_CRITICAL,
    MAV_SEVERITY_NOTICE,
    MAV_SEVERITY_WARNING,
    LinkStats,
    MavlinkLink,
)

RTA_OFF_TEXT = "RTA off: normal control"


def default_mount(plant: str) -> RigMount:
    """The rig's mount on ``plant``'s airframe as the simulation flies it (documented default)."""
    m = mcap_recording.default_mount(plant)
    return RigMount.on_airframe(m.r_bc, m.camera_b, m.probe_tip_b)


def exposure_time_s(record: TickRecord) -> float:
    """The record's frame time on its source's clock (s)."""
    return record.stream.frame_t_s if record.stream is not None else record.t_s


def rta_status(reason: str) -> tuple[int, str]:
    """The ``STATUSTEXT`` severity and text of a hand-over to the recovery law."""
    severity = MAV_SEVERITY_CRITICAL if reason.startswith("envelope:") else MAV_SEVERITY_WARNING
    return severity, f"RTA {reason}"


class MavlinkOutput:
    """Subscriber: one ``LANDING_TARGET`` per navigation record (``on_tick``) and a
    ``STATUSTEXT`` per run-time assurance hand-over (see the module's docstring)."""

    def __init__(self, url: str, mount: RigMount) -> None:
        self.mount = mount
        self.link = MavlinkLink(url)
        # the hand-over in force: (source, run, rta_reason) of the last record that had one
        self._rta: tuple[str, int, str] | None = None

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        if record.source == "upload":
            return
        pose = record.pose if record.lock else None
        self.link.send(landing_target(pose, max(0.0, exposure_time_s(record)), self.mount))
        self._rta_status(record)

    def _rta_status(self, record: TickRecord) -> None:
        """A ``STATUSTEXT`` when the recovery law takes over, or hands back."""
        now = None if record.rta_reason is None else (record.source, record.run, record.rta_reason)
        if now == self._rta:
            return
        if now is None:
            self.link.send_status(MAV_SEVERITY_NOTICE, RTA_OFF_TEXT)
        else:
            if self._rta is not None and self._rta[:2] != now[:2]:  # another run's
                self.link.send_status(MAV_SEVERITY_NOTICE, RTA_OFF_TEXT)
            self.link.send_status(*rta_status(now[2]))
        self._rta = now

    def health(self) -> str | None:
        """Why the MAVLink output is not working (None: it is)."""
        return self.link.health()

    def close(self) -> None:
        self.link.close()
