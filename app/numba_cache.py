"""Where numba caches the compiled loops: a folder keyed by the kernels' sources.

numba keys its on-disk cache by each source file's own time stamp and size, and freezes the
module-level constants a kernel reads from *other* modules at compile time
(``app/vision/blob_kernels.py`` reads ``OUT_COLUMNS`` from ``local_centroid_kernels.py``). A
checkout updated in place then loads a stale compiled loop (an ``IndexError`` at the first
frame). So, unless the operator set ``NUMBA_CACHE_DIR`` (the image does), the cache goes to a
folder named after a hash of every ``*kernels*.py`` source: any change to any of them starts a
fresh cache. numba falls back to its usual locations when the folder cannot be written.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

APP_DIR = Path(__file__).resolve().parent


def kernel_sources_digest(root: Path = APP_DIR) -> str:
    """SHA-1 (12 hex digits) over the paths and contents of every ``*kernels*.py`` under
    ``root``."""
    h = hashlib.sha1()
    for path in sorted(root.rglob("*kernels*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


def configure_numba_cache(root: Path = APP_DIR) -> str | None:
    """Set ``NUMBA_CACHE_DIR`` to ``root/__pycache__/numba-<digest>`` unless it is set (or
    numba already imported, when it is too late); returns the folder set, or None."""
    if "NUMBA_CACHE_DIR" in os.environ or "numba" in sys.modules:
        return None
    folder = str(root / "__pycache__" / f"numba-{kernel_sources_digest(root)}")
    os.environ["NUMBA_CACHE_DIR"] = folder
    return folder
