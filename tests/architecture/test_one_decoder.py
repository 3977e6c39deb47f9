"""One image decoder (issue 31 item 4): every encoded image the package reads — uploads,
checkerboards, pushed pairs, image folders, frame recordings, MCAP logs, the CLI — is decoded
by ``app/vision/io.py``'s ``decode_image``, so that the same pixels reach the same detection
whichever way a pair comes in. The calls are found with ``ast`` (a comment or a string does
not count)."""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
# the optics set's 16-bit linear renders (app/sim/optics_set.py) are no camera's frames: they
# are read as stored, before the sensor model makes camera frames of them
IMREAD_ALLOWED = {"app/sim/optics_set.py"}


def _calls(name: str) -> list[str]:
    """``module:line`` of every call ``<anything>.<name>(...)`` or ``<name>(...)`` in app/."""
    found = []
    for path in sorted(APP.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            f = node.func
            called = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
            if called == name:
                found.append(f"{path.relative_to(APP.parent)}:{node.lineno}")
    return found


def test_exactly_one_imdecode_call_site() -> None:
    sites = _calls("imdecode")
    assert len(sites) == 1 and sites[0].startswith("app/vision/io.py:"), sites


def test_image_files_are_read_through_the_decoder() -> None:
    sites = [s for s in _calls("imread") if s.split(":")[0] not in IMREAD_ALLOWED]
    assert not sites, f"cv2.imread outside app/vision/io.py's read_image: {sites}"
