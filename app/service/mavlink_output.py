"""The navigation stream as MAVLink 2 (``aar-dock serve --mavlink udpout:HOST:PORT``): a tick-loop
subscriber that turns each published navigation record into one ``LANDING_TARGET``
(:mod:`app.streams.landing_target`) sent by :class:`app.streams.mavlink_link.MavlinkLink`.

Only the configured source goes out:

- records of the active source's epoch (:mod:`app.service.source_epoch`): a tick whose producer
  was stopped or replaced on its way is dropped, and the check holds the switch's lock while
  it sends, so nothing of the old source follows a switch;
- camera/video/push/MCAP streams' records; the simulated stream's only when asked for
  (``simulated``: ``--mavlink-sim``, for SITL), then marked ``target_num`` =
  :data:`SIMULATED_TARGET_NUM` and announced by a ``STATUSTEXT`` when they begin; uploads
  never (a one-off pair is not the navigation stream).

A fix is valid (``position_valid`` 1) only while fresh: a record whose fix is older than
``max_age_s`` when it is sent goes out with ``position_valid`` 0 (the age: the record's latency
up to its publication — a camera's capture → published, the simulation's deadline → relayed,
a video's or pushed pair's read → published — plus the time since), and when no new
record follows a valid one within ``max_age_s`` (a stalled or switched source) a
``LANDING_TARGET`` with ``position_valid`` 0 withdraws it. ``time_usec`` is the frame's exposure
time on the source's clock: the stream's capture time, the simulation's time for simulated
ticks (a withdrawal: the last fix's, plus the time since it was sent).

The run-time assurance's hand-overs (the record's ``rta_reason``) are ``STATUSTEXT`` messages,
once per hand-over: when the recovery law takes over (``rta_reason`` from None to a reason, or
to another reason), ``MAV_SEVERITY_CRITICAL`` for an envelope recovery (``envelope: …``) and
``MAV_SEVERITY_WARNING`` for a break-away, the text ``RTA <reason>``; when it hands back
(``rta_reason`` back to None, or a record of another run or source), ``MAV_SEVERITY_NOTICE``,
``RTA off: normal control``. ``LANDING_TARGET`` is unchanged meanwhile (the vision fix stays
valid while the recovery law flies).
"""

from __future__ import annotations

import dataclasses
import threading
import time

from app.model.frames import RawFrame
from app.model.tick import TickRecord
from app.service.clock import Clock, MonotonicClock
from app.service.source_epoch import SourceEpoch
from app.streams.landing_target import RigMount, landing_target, no_target
from app.streams.mavlink_link import (
    MAV_SEVERITY_CRITICAL,
    MAV_SEVERITY_NOTICE,
    MAV_SEVERITY_WARNING,
    LinkStats,
    MavlinkLink,
)

RTA_OFF_TEXT = "RTA off: normal control"
SIMULATED_TARGET_NUM = 255  # LANDING_TARGET.target_num of a simulated target (real: 0)
SIMULATED_TEXT = "SIMULATED targets, target_num 255: not a real fix"  # one STATUSTEXT (≤ 50 B)
MAX_AGE_S = 0.25  # a fix older than this is not valid (Settings.mavlink_max_age_s)
# the record's latency up to its publication, by kind: the first of these timings it has (ms)
LATENCY_TIMINGS = ("frame_age", "relay", "step")


def exposure_time_s(record: TickRecord) -> float:
    """The record's frame time on its source's clock (s)."""
    return record.stream.frame_t_s if record.stream is not None else record.t_s


def fix_latency_s(record: TickRecord) -> float:
    """The record's latency from its frame's entry to its publication (s): a camera's
    capture time (``frame_age``), a paced simulation's deadline (``relay``), else the step."""
    for name in LATENCY_TIMINGS:
        value = record.timings_ms.get(name)
        if value is not None:
            return max(0.0, value / 1e3)
    return 0.0


@dataclasses.dataclass(frozen=True)
class SentFix:
    """The last valid fix sent: its exposure time (source clock, s), when it went out
    (monotonic, s) and its ``target_num``."""

    exposure_s: float
    sent_s: float
    target_num: int


def rta_status(reason: str) -> tuple[int, str]:
    """The ``STATUSTEXT`` severity and text of a hand-over to the recovery law."""
    severity = MAV_SEVERITY_CRITICAL if reason.startswith("envelope:") else MAV_SEVERITY_WARNING
    return severity, f"RTA {reason}"


class MavlinkOutput:
    """Subscriber: one ``LANDING_TARGET`` per navigation record (``on_tick``) and a
    ``STATUSTEXT`` per run-time assurance hand-over (see the module's docstring)."""

    def __init__(
        self,
        url: str,
        mount: RigMount,
        sources: SourceEpoch,
        *,
        simulated: bool = False,
        max_age_s: float = MAX_AGE_S,
        clock: Clock | None = None,
    ) -> None:
        """``sources``: the bus's active source (records of another epoch are dropped);
        ``simulated``: send the simulated stream too (marked); ``max_age_s``: the oldest a
        valid fix may be; ``clock``: the bus's (the records' ``clock_s``)."""
        if not max_age_s > 0:
            raise ValueError("max_age_s must be > 0")
        self.mount = mount
        self.sources = sources
        self.simulated = simulated
        self.max_age_s = max_age_s
        self.clock: Clock = clock or MonotonicClock()
        self.dropped = 0  # records not sent: another epoch's, or simulated ones not asked for
        self.stale = 0  # fixes sent as not valid for their age, and withdrawals
        self._send_lock = threading.Lock()  # a target and the freshness state together
        self._valid: SentFix | None = None  # the last valid fix while it is the newest sent
        self._sim_epoch: int | None = None  # the simulated epoch announced by STATUSTEXT
        # the hand-over in force: (source, run, rta_reason) of the last record that had one
        self._rta: tuple[str, int, str] | None = None
        self.link = MavlinkLink(url)
        self._stop = threading.Event()
        self._watch = threading.Thread(target=self._withdraw_stale, name="mavlink-stale")
        self._watch.daemon = True
        self._watch.start()

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        if record.source == "upload":
            return
        simulated = record.source == "sim"
        if simulated and not self.simulated:
            self.dropped += 1
            return
        with self.sources.current(record.source_epoch) as current:
            if not current:  # its source was stopped or replaced on the way
                self.dropped += 1
                return
            if simulated and self._sim_epoch != record.source_epoch:
                self._sim_epoch = record.source_epoch
                self.link.send_status(MAV_SEVERITY_NOTICE, SIMULATED_TEXT)
            self._send(record, simulated)
            if simulated:
                self._rta_status(record)

    def _send(self, record: TickRecord, simulated: bool) -> None:
        """The record's ``LANDING_TARGET``; not valid when its fix is older than the limit."""
        age_s = fix_latency_s(record) + max(0.0, self.clock.now() - record.clock_s)
        fresh = age_s <= self.max_age_s
        pose = record.pose if record.lock and fresh else None
        t_s = max(0.0, exposure_time_s(record))
        target = landing_target(pose, t_s, self.mount)
        if simulated:
            target = dataclasses.replace(target, target_num=SIMULATED_TARGET_NUM)
        with self._send_lock:
            self.link.send(target)
            if record.lock and not fresh:
                self.stale += 1
            valid = target.position_valid == 1
            self._valid = SentFix(t_s, time.monotonic(), target.target_num) if valid else None

    def _withdraw_stale(self) -> None:
        """A valid fix not followed by another record within ``max_age_s``: withdrawn."""
        while not self._stop.wait(self.max_age_s / 5):
            with self._send_lock:
                last = self._valid
                elapsed = time.monotonic() - last.sent_s if last is not None else 0.0
                if last is None or elapsed <= self.max_age_s:
                    continue
                self._valid = None
                self.stale += 1
                withdrawal = no_target(last.exposure_s + elapsed)
                self.link.send(dataclasses.replace(withdrawal, target_num=last.target_num))

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
        self._stop.set()
        self._watch.join(timeout=2.0)
        self.link.close()
