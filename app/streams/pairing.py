"""Left/right pairing by timestamps with a maximum skew.

Two heads are compared: if their times differ by at most ``max_skew_s`` they form a pair;
otherwise the older frame can have no partner (the other side has moved past it) and is
dropped and counted. A side that ends ends the stream.
"""

from __future__ import annotations

from app.model.frames import StereoFrame
from app.streams.readers import MonoReader
from app.types import UInt8Array


class TimestampPairer:
    def __init__(self, left: MonoReader, right: MonoReader, max_skew_s: float) -> None:
        self.left, self.right = left, right
        self.max_skew_s = max_skew_s
        self.dropped = 0  # frames without a partner within the skew
        self._l: tuple[float, UInt8Array] | None = None
        self._r: tuple[float, UInt8Array] | None = None
        self.seq = 0

    def next_pair(self) -> StereoFrame | None:
        """The next pair within the skew; ``None`` when a side has ended."""
        while True:
            if self._l is None:
                self._l = self.left.read()
            if self._r is None:
                self._r = self.right.read()
            if self._l is None or self._r is None:
                return None
            (tl, il), (tr, ir) = self._l, self._r
            if abs(tl - tr) <= self.max_skew_s:
                self._l = self._r = None
                frame = StereoFrame(
                    left=il, right=ir, t_s=0.5 * (tl + tr), seq=self.seq, t_left_s=tl, t_right_s=tr
                )
                self.seq += 1
                return frame
            self.dropped += 1
            if tl < tr:
                self._l = None
            else:
                self._r = None
