"""app.streams.mavlink_link: a pymavlink receiver on UDP loopback (the reader of the field, not
ours) gets MAVLink 2 HEARTBEATs and LANDING_TARGETs carrying the mapped values."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink import mavutil

from app.streams.landing_target import LandingTarget, no_target
from app.streams.mavlink_link import MavlinkLink, check_url, statustext_chunks


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _target(i: int) -> LandingTarget:
    return LandingTarget(
        time_usec=1_000_000 + 20_000 * i,
        angle_x=0.01 * i,
        angle_y=-0.02,
        distance=4.25,
        size_x=0.0176,
        size_y=0.0176,
        x=3.1,
        y=-0.25,
        z=0.125,
        q=(1.0, 0.0, 0.0, 0.0),
        position_valid=1,
    )


def test_heartbeat_and_landing_targets_reach_a_pymavlink_listener() -> None:
    port = _free_udp_port()
    rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")
    link = MavlinkLink(f"udpout:127.0.0.1:{port}", heartbeat_hz=5.0)
    try:
        assert link.mavlink_version == 2
        hb = rx.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None
        assert hb.type == mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_INVALID
        assert hb.get_srcComponent() == mavutil.mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
        assert hb.get_msgbuf()[0] == 0xFD  # a MAVLink 2 frame
        sent = [_target(i) for i in range(10)] + [no_target(1.3)]
        for t in sent:
            link.send(t)
        got = []
        deadline = time.monotonic() + 5
        while len(got) < len(sent) and time.monotonic() < deadline:
            m = rx.recv_match(type="LANDING_TARGET", blocking=True, timeout=1)
            if m is not None:
                got.append(m)
        assert len(got) == len(sent)
        for m, t in zip(got, sent, strict=True):
            assert m.time_usec == t.time_usec
            assert m.frame == mavutil.mavlink.MAV_FRAME_BODY_FRD
            assert m.type == mavutil.mavlink.LANDING_TARGET_TYPE_VISION_FIDUCIAL
            assert m.position_valid == t.position_valid
            # float32 on the wire: equal to its precision (distance within 1 mm and far better)
            assert m.distance == pytest.approx(t.distance, abs=1e-6)
            assert (m.x, m.y, m.z) == pytest.approx((t.x, t.y, t.z), abs=1e-6)
            assert m.angle_x == pytest.approx(t.angle_x, abs=1e-7)
            assert list(m.q) == pytest.approx(list(t.q), abs=1e-7)
        assert link.stats.targets == 11 and link.stats.targets_valid == 10
        assert link.stats.heartbeats >= 1 and link.stats.send_errors == 0
    finally:
        link.close()
        rx.close()


@pytest.mark.parametrize(
    "url", ["http://127.0.0.1:14550", "udpout:127.0.0.1", "udpout::14550", "udpout:h:99999", "x"]
)
def test_bad_addresses_are_refused_with_what_is_expected(url: str) -> None:
    with pytest.raises(ValueError, match="udpout:HOST:PORT|HOST:PORT"):
        check_url(url)


def test_statustext_chunks_are_ascii_and_end_with_a_short_chunk() -> None:
    assert statustext_chunks("RTA envelope: α 10.2° above 10.0°") == [
        b"RTA envelope: alpha 10.2 deg above 10.0 deg"
    ]
    assert statustext_chunks("bank ±45° − é") == [b"bank +/-45 deg - e"]
    assert [len(c) for c in statustext_chunks("x" * 120)] == [50, 50, 20]
    assert [len(c) for c in statustext_chunks("x" * 100)] == [50, 50, 0]  # the end mark
    assert statustext_chunks("x" * 50) == [b"x" * 50]  # one message (id 0) needs none
    assert sum(len(c) for c in statustext_chunks("x" * 1000)) == 200  # cut to 200 bytes
