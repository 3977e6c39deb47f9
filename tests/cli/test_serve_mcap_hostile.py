"""Issue 33, cases 1–3 through ``aar-dock serve --source mcap:FILE`` (the service's door; the
same files through ``track``: test_track_mcap.py). The service refuses such a log at start:
one line and exit 2, no traceback, the child's peak RSS (read from outside, ``os.wait4``)
≤ 1.5 GB, within 60 s — before the fix it reached 3.9–5.2 GB and died with a traceback."""

from __future__ import annotations

import struct
from pathlib import Path

from mcap.opcode import Opcode

from tests.support.hostile_mcap import (
    MAX_RSS_MB,
    MAX_WALL_S,
    chunk,
    finish,
    head_records,
    run_measured,
    unpaired_images,
    zstd_of_zeros,
)

MiB = 1 << 20


def _serve_refuses(path: Path, tmp: Path, *words: str) -> None:
    got = run_measured(
        ["serve", "--source", f"mcap:{path}", "--no-viser", "--port", "0"], tmp, MAX_WALL_S
    )
    lines = [ln for ln in got.stderr.splitlines() if ln.strip()]
    assert got.returncode == 2 and "Traceback" not in got.stderr, got.stderr[-2000:]
    assert any(all(w in ln for w in words) for ln in lines), lines[-5:]
    assert got.peak_rss_mb <= MAX_RSS_MB and got.wall_s <= MAX_WALL_S, (got.peak_rss_mb, got.wall_s)


def test_serve_refuses_a_zstd_bomb_and_unpaired_images_bounded(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("AAR_STREAM_ROOTS", str(tmp_path))
    head = struct.pack("<BQHIQQ", Opcode.MESSAGE, (1 << 30) - 9, 1, 0, 10**9, 10**9)
    bomb = zstd_of_zeros((1 << 30) - len(head), prefix=head)
    honest = tmp_path / "bomb.mcap"
    honest.write_bytes(finish(head_records() + chunk(b"", data=bomb, declared_size=1 << 30)))
    _serve_refuses(honest, tmp_path, "over the limit")
    unpaired = unpaired_images(tmp_path / "unpaired.mcap", 1000, MiB)  # 2 GB of one-sided images
    _serve_refuses(unpaired, tmp_path, "holds no stereo pair")
