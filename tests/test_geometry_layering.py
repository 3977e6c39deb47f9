"""The geometry floor stays the bottom layer: no module of ``app/geometry`` imports a process
pool, a progress bar, a plotting library or the calibration package built on it (every import
statement, at module level or inside a function, read from the source with ``ast``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
GEOMETRY = REPO / "app" / "geometry"
CALIBRATION = REPO / "app" / "calibration"
# top-level packages (and the layer above) the geometry floor must not import
FORBIDDEN = ("concurrent", "multiprocessing", "tqdm", "matplotlib", "app.calibration")


def imported_modules(path: Path) -> list[str]:
    """Every module an ``import`` / ``from … import`` statement of ``path`` names (for
    ``from a import b``: ``a`` and ``a.b``, since ``b`` may be a module)."""
    out: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            out.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"
            base = node.module or ""
            out.append(base)
            out.extend(f"{base}.{alias.name}" for alias in node.names)
    return out


def _forbidden(name: str) -> bool:
    return any(name == f or name.startswith(f + ".") for f in FORBIDDEN)


GEOMETRY_MODULES = sorted(GEOMETRY.glob("*.py"))


def test_geometry_has_modules() -> None:
    assert len(GEOMETRY_MODULES) >= 5  # the glob sees the package


@pytest.mark.parametrize("path", GEOMETRY_MODULES, ids=lambda p: p.name)
def test_geometry_imports_no_pool_progress_bar_plotting_or_calibration(path: Path) -> None:
    bad = sorted({m for m in imported_modules(path) if _forbidden(m)})
    assert bad == [], f"app/geometry/{path.name} imports {bad}"


def test_calibration_builds_on_geometry() -> None:
    """The direction of the layering: app/calibration imports app.geometry (the camera model,
    projection, triangulation), which the test above keeps from importing it back."""
    names = {m for p in CALIBRATION.glob("*.py") for m in imported_modules(p)}
    assert any(m.startswith("app.geometry.") for m in names)
