"""The active source's epoch: begin / end / current, and a switch that waits for a send in
flight (what makes "nothing of the old source after a switch" hold)."""

from __future__ import annotations

import threading
import time

from app.service.source_epoch import ActiveSource, SourceEpoch


def test_epochs_follow_begin_and_end() -> None:
    s = SourceEpoch()
    assert s.active == ActiveSource(None, 0)
    sim = s.begin("sim")
    with s.current(sim) as ok:
        assert ok
    video = s.begin("video")  # a switch: the simulation's ticks are no longer current
    assert video != sim
    for epoch, want in ((sim, False), (video, True), (None, False)):
        with s.current(epoch) as ok:
            assert ok is want
    s.end(sim)  # an old epoch's end changes nothing
    assert s.active == ActiveSource("video", video)
    s.end(video)  # stopped: nothing is current, not even its own epoch
    with s.current(video) as ok:
        assert not ok
    assert s.active.kind is None


def test_a_switch_waits_for_the_send_in_flight() -> None:
    s = SourceEpoch()
    old = s.begin("push")
    order: list[str] = []
    inside = threading.Event()

    def send() -> None:
        with s.current(old) as ok:
            assert ok
            inside.set()
            time.sleep(0.2)
            order.append("sent")

    t = threading.Thread(target=send)
    t.start()
    assert inside.wait(5)
    s.begin("video")
    order.append("switched")
    t.join()
    assert order == ["sent", "switched"]
