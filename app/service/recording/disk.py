"""The recordings' disk: advisory locks (which recordings are live in some process), atomic
and short-write-safe writes, ``fsync`` of a directory, the free space, and reading a JSONL."""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path
from typing import IO

from app.types import JsonObject

try:  # POSIX advisory locks: which recordings are live in some process
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]


def free_mb(directory: Path) -> float | None:
    """Free space (MB) of the file system holding ``directory``; None if it cannot be read."""
    try:
        return shutil.disk_usage(directory).free / 1e6
    except OSError:
        return None


def try_lock(fh: IO[bytes]) -> bool:
    """Non-blocking exclusive ``flock``; released when the file is closed or the process dies."""
    if fcntl is None:  # pragma: no cover
        return True
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)  # a torn temp file must not hold the space it took
        raise
    fsync_dir(path.parent)


def write_all(fh: IO[bytes], data: bytes) -> None:
    """Unbuffered file: all of ``data`` or ``OSError`` (a short write is retried)."""
    view = memoryview(data)
    while view:
        n = fh.write(view)
        if not n:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view = view[n:]


def wall_time(line: bytes | None) -> float | None:
    if line is None:
        return None
    try:
        value = json.loads(line).get("wall_time")
    except (ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, int | float) else None


def read_jsonl(path: Path) -> list[JsonObject]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
