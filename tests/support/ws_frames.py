"""Raw WebSocket frames for the attack tests: a client frame's header, the server's close."""

from __future__ import annotations

import socket
import struct


def frame_header(opcode: int, length: int) -> bytes:
    """A client frame's header with a zero mask (so the payload goes as it is)."""
    b0 = 0x80 | opcode
    if length < 126:
        head = struct.pack("!BB", b0, 0x80 | length)
    elif length < 65536:
        head = struct.pack("!BBH", b0, 0x80 | 126, length)
    else:
        head = struct.pack("!BBQ", b0, 0x80 | 127, length)
    return head + b"\0\0\0\0"


def read_close(s: socket.socket, timeout: float = 10.0) -> tuple[int, str] | None:
    """The close frame the server sends (skipping data frames); None if the socket just ends."""
    s.settimeout(timeout)
    buf = b""
    try:
        while True:
            while len(buf) < 2:
                chunk = s.recv(65536)
                if not chunk:
                    return None
                buf += chunk
            opcode, n = buf[0] & 0x0F, buf[1] & 0x7F
            start = 2 + {126: 2, 127: 8}.get(n, 0)
            while len(buf) < start:
                chunk = s.recv(65536)
                if not chunk:
                    return None
                buf += chunk
            if n == 126:
                n = struct.unpack("!H", buf[2:4])[0]
            elif n == 127:
                n = struct.unpack("!Q", buf[2:10])[0]
            while len(buf) < start + n:
                chunk = s.recv(65536)
                if not chunk:
                    return None
                buf += chunk
            payload, buf = buf[start : start + n], buf[start + n :]
            if opcode == 0x8:
                code = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else 1005
                return code, payload[2:].decode(errors="replace")
    except OSError:
        return None
