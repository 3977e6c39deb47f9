"""No module of the package is several algorithms glued together: none is longer than 800
lines (docs/development.md: aim for ≤ 600)."""

from __future__ import annotations

from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
LIMIT_LINES = 800


def test_no_module_exceeds_the_limit() -> None:
    sizes = {
        str(p.relative_to(APP.parent)): len(p.read_text().splitlines())
        for p in APP.rglob("*.py")
        if "__pycache__" not in p.parts
    }
    assert len(sizes) > 100, "the package was not found"
    long = {path: n for path, n in sizes.items() if n > LIMIT_LINES}
    assert not long, f"modules over {LIMIT_LINES} lines: {long}"
