"""The navigation stream as MAVLink 2 (``aar-dock serve --mavlink udpout:HOST:PORT``): a tick-loop
subscriber that turns each published navigation record into one ``LANDING_TARGET``
(:mod:`app.streams.landing_target`) sent by :class:`app.streams.mavlink_link.MavlinkLink`.

Records of the simulated stream and of camera/video/push streams are sent; uploads are not
(a one-off pair is not the navigation stream). ``time_usec`` is the frame's exposure time on the
source's clock: the stream's capture time, the simulation's time for simulated ticks.
"""

from __future__ import annotations

from app.server import mcap_recording
from app.server.schemas import TickRecord
from app.streams.frames import RawFrame
from app.streams.landing_target import RigMount, landing_target
from app.streams.mavlink_link import LinkStats, MavlinkLink


def default_mount(plant: str) -> RigMount:
    """The rig's mount on ``plant``'s airframe as the simulation flies it (documented default)."""
    m = mcap_recording.default_mount(plant)
    return RigMount.on_airframe(m.r_bc, m.camera_b, m.probe_tip_b)


def exposure_time_s(record: TickRecord) -> float:
    """The record's frame time on its source's clock (s)."""
    return record.stream.frame_t_s if record.stream is not None else record.t_s


class MavlinkOutput:
    """Subscriber: one ``LANDING_TARGET`` per navigation record (``on_tick``)."""

    def __init__(self, url: str, mount: RigMount) -> None:
        self.mount = mount
        self.link = MavlinkLink(url)

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        if record.source == "upload":
            return
        pose = record.pose if record.lock else None
        self.link.send(landing_target(pose, max(0.0, exposure_time_s(record)), self.mount))

    def health(self) -> str | None:
        """Why the MAVLink output is not working (None: it is)."""
        return self.link.health()

    def close(self) -> None:
        self.link.close()
