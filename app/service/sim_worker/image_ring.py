"""Camera images of the simulation worker in shared memory: a ring of stamped slots.

The images (2 × 1.3 MB per tick) never go through the pipe: the worker copies each pair into
the next slot of a ring in :mod:`multiprocessing.shared_memory` (a seqlock-style stamp per
slot), and the parent's tick reads them lazily, only when a subscriber asks for them (the 3-D
scene, at its image rate). A slot overwritten before it was read gives ``None``.
"""

from __future__ import annotations

import struct
import threading
from multiprocessing import shared_memory

import numpy as np

from app.types import UInt8Array

RING_SLOTS = 8  # ≈ 0.23 s of ticks at 30 Hz before a slot is reused
_HDR = struct.Struct("<qqqqq")  # stamp, left h, left w, right h, right w
_HDR_BYTES = 64


class ImageRing:
    """``slots`` pairs of uint8 images in one shared-memory block, each slot stamped.

    Writer (worker): stamp ← −1, data, shapes, stamp ← tick id. Reader (parent): stamp, copy,
    stamp again; the copy is valid only if both stamps equal the tick id it wants.
    """

    def __init__(
        self, shm: shared_memory.SharedMemory, slots: int, capacity: int, *, owner: bool
    ) -> None:
        self.shm = shm
        self.slots = slots
        self.capacity = capacity  # bytes for both images of one slot
        self.slot_bytes = _HDR_BYTES + ((capacity + 63) // 64) * 64
        self.owner = owner
        self._lock = threading.Lock()
        self._closed = False

    @classmethod
    def create(cls, slots: int, pixels_per_image: int) -> ImageRing:
        capacity = 2 * pixels_per_image
        slot_bytes = _HDR_BYTES + ((capacity + 63) // 64) * 64
        shm = shared_memory.SharedMemory(create=True, size=slots * slot_bytes)
        ring = cls(shm, slots, capacity, owner=True)
        buf = shm.buf
        assert buf is not None
        for i in range(slots):
            _HDR.pack_into(buf, i * slot_bytes, -1, 0, 0, 0, 0)
        return ring

    @classmethod
    def attach(cls, name: str, slots: int, capacity: int) -> ImageRing:
        return cls(shared_memory.SharedMemory(name=name), slots, capacity, owner=False)

    @property
    def name(self) -> str:
        return str(self.shm.name)

    def write(self, slot: int, stamp: int, left: UInt8Array, right: UInt8Array) -> bool:
        """Worker side; ``False`` if the pair does not fit (or is not 2-D uint8)."""
        if left.dtype != np.uint8 or right.dtype != np.uint8 or left.ndim != 2 or right.ndim != 2:
            return False
        nl, nr = left.size, right.size
        if nl + nr > self.capacity:
            return False
        buf = self.shm.buf
        assert buf is not None  # open (the worker closes its ring when it exits)
        base = slot * self.slot_bytes
        data = base + _HDR_BYTES
        _HDR.pack_into(buf, base, -1, 0, 0, 0, 0)
        np.frombuffer(buf, np.uint8, count=nl, offset=data).reshape(left.shape)[...] = left
        np.frombuffer(buf, np.uint8, count=nr, offset=data + nl).reshape(right.shape)[...] = right
        _HDR.pack_into(buf, base, stamp, left.shape[0], left.shape[1], *right.shape)
        return True

    def read(self, slot: int, stamp: int) -> tuple[UInt8Array, UInt8Array] | None:
        """Parent side: copies of the pair stamped ``stamp``, or ``None`` if overwritten."""
        with self._lock:
            if self._closed:
                return None
            buf = self.shm.buf
            assert buf is not None  # not closed (checked above)
            base = slot * self.slot_bytes
            data = base + _HDR_BYTES
            s0, lh, lw, rh, rw = _HDR.unpack_from(buf, base)
            if s0 != stamp:
                return None
            nl, nr = lh * lw, rh * rw
            left = np.frombuffer(buf, np.uint8, count=nl, offset=data).reshape(lh, lw).copy()
            right = np.frombuffer(buf, np.uint8, count=nr, offset=data + nl).reshape(rh, rw).copy()
            if _HDR.unpack_from(buf, base)[0] != stamp:
                return None
            return left, right

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self.shm.close()
            except BufferError:  # pragma: no cover - a view still exported: freed with it
                pass
            if self.owner:
                try:
                    self.shm.unlink()
                except FileNotFoundError:  # pragma: no cover
                    pass
