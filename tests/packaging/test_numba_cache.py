"""The compiled loops' cache follows the kernels' sources (app/numba_cache.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from app.numba_cache import kernel_sources_digest


def test_the_digest_changes_with_any_kernel_source(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x_kernels.py").write_text("OUT_COLUMNS = 12\n")
    (tmp_path / "b_kernels.py").write_text("def f():\n    pass\n")
    (tmp_path / "other.py").write_text("x = 1\n")
    before = kernel_sources_digest(tmp_path)
    (tmp_path / "other.py").write_text("x = 2\n")  # not a kernel: same cache
    assert kernel_sources_digest(tmp_path) == before
    (tmp_path / "a" / "x_kernels.py").write_text("OUT_COLUMNS = 14\n")  # a constant others read
    assert kernel_sources_digest(tmp_path) != before


def test_importing_the_package_points_numba_at_the_keyed_folder() -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    code = "import app, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith(f"numba-{kernel_sources_digest()}")
    env["NUMBA_CACHE_DIR"] = "/tmp/operator-choice"  # the operator's setting wins
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.stdout.strip() == "/tmp/operator-choice"
