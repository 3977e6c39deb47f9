"""The tests mirror the source: every test directory is a package of ``app`` (or one of the
few that are not: shared support, the architecture checks, the documents, the packaging), and
no test module imports another test module (what tests share lives in ``tests/support``)."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
APP = TESTS.parent / "app"
NOT_PACKAGES = {"support", "architecture", "docs", "packaging", "data"}


def test_every_test_directory_mirrors_a_package() -> None:
    dirs = {p.name for p in TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))}
    packages = {p.name for p in APP.iterdir() if (p / "__init__.py").is_file()}
    assert {"vision", "geometry", "server"} <= dirs
    assert dirs - NOT_PACKAGES <= packages, sorted(dirs - NOT_PACKAGES - packages)
    flat = sorted(p.name for p in TESTS.glob("test_*.py"))
    assert not flat, f"test files outside the mirrored tree: {flat}"


def test_no_test_module_imports_another() -> None:
    bad = []
    for path in TESTS.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                if name.split(".")[-1].startswith("test_") or name.startswith("test_"):
                    bad.append(f"{path.relative_to(TESTS)}:{node.lineno} imports {name}")
    assert not bad, bad
