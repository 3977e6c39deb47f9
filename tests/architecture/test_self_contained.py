"""The tests and benchmarks need nothing outside the repository: a fresh clone with nothing beside
it runs its own tests. No file under ``tests/`` or ``benchmarks/`` names a path out of it
(``../shared``, ``/work/...``, a ``"shared"`` joined to a path, a parent of the repository root
reached from ``__file__``); the data they read lives in ``tests/data`` (Bouguet's photographs in
``tests/data/real/bouguet_stereo``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROOTS = ("tests", "benchmarks")
TEXT = {".py", ".md", ".json", ".toml", ".txt", ".cfg", ".ini", ".sh", ".yml", ".yaml"}
# out of the repository in a string: a sibling ``shared`` folder, or an absolute /work/ path
OUTSIDE = re.compile(r"(?<![\w.])\.\.[/\\]+shared\b|(?<![\w.])/work/")
PASS = {"Path", "PurePath", "PurePosixPath", "abspath", "realpath", "resolve", "absolute"}
PATHS = (ast.Attribute, ast.Subscript, ast.Call)  # expressions that may make a path
JOIN = {"Path", "PurePath", "PurePosixPath", "joinpath", "join"}
BOUGUET = REPO / "tests" / "data" / "real" / "bouguet_stereo"
SELF = Path(__file__).resolve()  # spells the forbidden forms; the second test checks it


def _ups(node: ast.AST, names: dict[str, int]) -> int | None:
    """How far above ``__file__`` a path expression points (the file 0, its folder 1, ...), or
    None when the expression is not built from ``__file__``."""
    if isinstance(node, ast.Name):
        return 0 if node.id == "__file__" else names.get(node.id)
    if isinstance(node, ast.Attribute) and node.attr == "parent":
        up = _ups(node.value, names)
        return None if up is None else up + 1
    if (
        isinstance(node, ast.Subscript)
        and isinstance(node.value, ast.Attribute)
        and node.value.attr == "parents"
        and isinstance(node.slice, ast.Constant)
        and isinstance(node.slice.value, int)
    ):
        up = _ups(node.value.value, names)
        return None if up is None else up + 1 + node.slice.value
    if isinstance(node, ast.Call):
        func = node.func
        name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")
        if name == "dirname" and len(node.args) == 1:
            up = _ups(node.args[0], names)
            return None if up is None else up + 1
        if name in PASS and isinstance(func, ast.Attribute) and not node.args:
            return _ups(func.value, names)  # x.resolve(), x.absolute()
        if name in PASS and len(node.args) == 1:
            return _ups(node.args[0], names)  # Path(x), os.path.abspath(x)
    return None


def _is_shared(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and re.split(r"[/\\]", node.value)[0] == "shared"
    )


def outside_paths(source: str, rel: Path) -> list[str]:
    """``rel:line what`` for each path out of the repository in ``source`` (the file at ``rel``,
    relative to the repository root)."""
    bad = {
        f"{rel}:{n} {m.group(0)!r}"
        for n, line in enumerate(source.splitlines(), 1)
        for m in OUTSIDE.finditer(line)
    }
    if rel.suffix != ".py":
        return sorted(bad)
    root = len(rel.parts)  # __file__'s parents[len - 1] is the repository root
    tree = ast.parse(source, str(rel))
    names: dict[str, int] = {}
    for node in ast.walk(tree):  # breadth first: module-level names before the uses below them
        if isinstance(node, ast.ImportFrom) and node.module == "app.resources":
            names.update({a.asname or a.name: root for a in node.names if a.name == "REPO_ROOT"})
        elif isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            up = _ups(node.value, names)
            for t in targets:
                if isinstance(t, ast.Name) and up is not None:
                    names[t.id] = up
    for node in ast.walk(tree):
        up = _ups(node, names) if isinstance(node, PATHS) else None
        if up is not None and up > root:
            bad.add(f"{rel}:{node.lineno} {ast.unparse(node)!r} is above the repository root")
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and _is_shared(node.right):
            bad.add(f"{rel}:{node.lineno} {ast.unparse(node)!r} joins 'shared' to a path")
        if isinstance(node, ast.Call) and any(map(_is_shared, node.args)):
            func = node.func
            if (func.id if isinstance(func, ast.Name) else getattr(func, "attr", "")) in JOIN:
                bad.add(f"{rel}:{node.lineno} {ast.unparse(node)!r} joins 'shared' to a path")
    return sorted(bad)


def test_no_test_or_benchmark_reads_outside_the_repository() -> None:
    bad = []
    for top in ROOTS:
        for path in sorted((REPO / top).rglob("*")):
            if path.is_file() and path.suffix in TEXT and path != SELF:
                rel = path.relative_to(REPO)
                bad += outside_paths(path.read_text(encoding="utf-8"), rel)
    assert not bad, bad


def test_the_check_catches_paths_out_of_the_repository() -> None:
    """The forms that read ``../shared`` before the data moved into ``tests/data``, and a few
    spellings of the same; and what stays inside is not flagged."""
    rel = Path("tests/calibration/test_x.py")
    head = "from pathlib import Path\nREPO = Path(__file__).resolve().parents[2]\n"
    outside = [
        'B = REPO.parent / "shared" / "data" / "real" / "bouguet_stereo"',
        'B = Path(__file__).resolve().parents[3] / "data"',
        'B = Path(__file__).parent.parent.parent.parent / "x"',
        'B = REPO / "shared"',
        'B = Path("../shared/data/real")',
        'B = "/work/shared/data/real/bouguet_stereo"',
        'import os\nB = os.path.join(os.path.dirname(__file__), "..", "..", "shared")',
        "B = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(__file__))))",
        'from app.resources import REPO_ROOT\nB = REPO_ROOT.parent / "x"',
        '"""Reads ``../shared/data`` beside the repository."""',
    ]
    for line in outside:
        assert outside_paths(head + line, rel), line
    inside = [
        'B = REPO / "tests" / "data" / "real" / "bouguet_stereo"',
        'B = Path(__file__).resolve().parents[1] / "data" / "optics"',
        'from app.resources import REPO_ROOT\nB = REPO_ROOT / "sample_data"',
        'url = "/api/v1/recordings/../../etc"',
        "# two shared cores on a loaded machine",
    ]
    for line in inside:
        assert not outside_paths(head + line, rel), line
    assert outside_paths('BOUGUET = Path("../shared/data/real/bouguet_stereo")', rel)
    assert not outside_paths("Shared data lives in `tests/data`.", Path("tests/x.md"))


def test_bouguet_set_is_in_the_repository() -> None:
    """The real photographs the calibration tests read, with the note on their origin."""
    lefts = sorted(p.name for p in BOUGUET.glob("left*.jpg"))
    rights = sorted(p.name for p in BOUGUET.glob("right*.jpg"))
    assert len(lefts) == len(rights) == 13
    assert [n[4:] for n in lefts] == [n[5:] for n in rights]
    note = (BOUGUET / "README.md").read_text(encoding="utf-8")
    assert "Bouguet" in note and "OpenCV" in note and "Apache-2.0" in note
