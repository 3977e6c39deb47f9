"""docs/architecture.md names only what exists: every backticked ``app/…`` and ``tests/…`` path,
every function of its stage tables in the module on the same row, every dotted name
(``module.function``, ``Class.method``) and class name in its prose; and the stage tables cover
each stage of the navigation pipeline and of the docking loop.

The definitions are read with ``ast`` (nothing is imported), so a renamed or moved function
fails here until the document follows it."""

from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

from app.resources import REPO_ROOT

DOC = REPO_ROOT / "docs" / "architecture.md"
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
CODE = re.compile(r"`([^`\n]+)`")
DOTTED = re.compile(r"^[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+$")
CLASS_NAME = re.compile(r"^[A-Z][a-z]\w*$")
FILE_SUFFIXES = (".py", ".md", ".json", ".jsonl", ".mcap", ".viser", ".toml", ".txt")
PIPELINE_STAGES = (
    "calibration",
    "blobs",
    "centroids",
    "IHWT",
    "matching",
    "triangulation",
    "ring fit",
    "centre and normal",
)
LOOP_STAGES = (
    "sense",
    "estimate",
    "guide",
    "control",
    "propagate",
    "contact",
    "recovery law",
    "monitor",
    "outcomes",
)


def _text() -> str:
    return FENCE.sub("", DOC.read_text(encoding="utf-8"))


@cache
def defined_names(path: Path) -> frozenset[str]:
    """What a module defines: its top-level functions, classes and assigned names, and each
    class's methods and attributes as ``Class.name``."""

    def targets(node: ast.stmt) -> list[str]:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            return [node.name]
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            return [node.target.id]
        if isinstance(node, ast.Assign):
            return [t.id for t in node.targets if isinstance(t, ast.Name)]
        return []

    names: set[str] = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        names.update(targets(node))
        if isinstance(node, ast.ClassDef):
            names.update(f"{node.name}.{m}" for item in node.body for m in targets(item))
    return frozenset(names)


@cache
def modules() -> tuple[Path, ...]:
    return tuple(sorted((REPO_ROOT / "app").rglob("*.py")))


def _module_name(path: Path) -> str:
    return path.parent.name if path.name == "__init__.py" else path.stem


def resolves(dotted: str) -> bool:
    """``module.name`` (a module's file stem, or a dotted ``app.…`` path) or ``Class.member``
    / ``function`` defined in some module of ``app``."""
    head, _, rest = dotted.partition(".")
    for path in modules():
        names = defined_names(path)
        if dotted in names or (_module_name(path) == head and rest in names):
            return True
    parts = dotted.split(".")
    for cut in range(len(parts) - 1, 0, -1):  # app.x.y.name: the longest module prefix
        base = REPO_ROOT.joinpath(*parts[:cut])
        for path in (base.with_suffix(".py"), base / "__init__.py"):
            if path.is_file() and ".".join(parts[cut:]) in defined_names(path):
                return True
    return False


def stage_tables() -> list[list[list[str]]]:
    """The tables whose header has a ``module`` and a ``function`` column: their rows' cells."""
    tables: list[list[list[str]]] = []
    lines = _text().splitlines()
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if "module" in cells and "function" in cells and i + 1 < len(lines):
            rows = []
            for row in lines[i + 2 :]:
                if not row.startswith("|"):
                    break
                rows.append([c.strip() for c in row.strip().strip("|").split("|")])
            tables.append([cells, *rows])
    return tables


def test_every_cited_path_exists():
    cited = {t.split("::")[0] for t in CODE.findall(_text()) if t.startswith(("app/", "tests/"))}
    assert cited
    missing = sorted(t for t in cited if not (REPO_ROOT / t.rstrip("/")).exists())
    assert not missing, f"docs/architecture.md cites paths that do not exist: {missing}"


def test_every_stage_table_row_names_what_its_module_defines():
    tables = stage_tables()
    assert len(tables) == 2, "the pipeline's and the docking loop's stage tables"
    problems = []
    for header, *rows in tables:
        col_mod, col_fn = header.index("module"), header.index("function")
        for row in rows:
            paths = CODE.findall(row[col_mod])
            if len(paths) != 1 or not paths[0].endswith(".py"):
                problems.append(f"{row}: one module (.py) per row")
                continue
            path = REPO_ROOT / paths[0]
            if not path.is_file():
                problems.append(f"{paths[0]}: no such module")
                continue
            functions = CODE.findall(row[col_fn])
            if not functions:
                problems.append(f"{row}: no function named")
            problems += [
                f"{paths[0]} defines no {name}"
                for name in functions
                if name not in defined_names(path)
            ]
    assert not problems, "\n".join(problems)


def test_the_stage_tables_cover_the_pipeline_and_the_loop():
    tables = stage_tables()
    assert len(tables) == 2, "the pipeline's and the docking loop's stage tables"
    pipeline, loop = tables
    for table, stages in ((pipeline, PIPELINE_STAGES), (loop, LOOP_STAGES)):
        named = " / ".join(row[0] for row in table[1:])
        missing = [s for s in stages if s not in named]
        assert not missing, f"stages without a row: {missing}"


def test_every_dotted_and_class_name_in_the_text_exists():
    tokens = set(CODE.findall(_text()))
    dotted = {t for t in tokens if DOTTED.match(t) and not t.endswith(FILE_SUFFIXES)}
    classes = {t for t in tokens if CLASS_NAME.match(t)}
    assert dotted and classes
    missing = sorted(t for t in dotted | classes if not resolves(t))
    assert not missing, f"docs/architecture.md names what the code does not define: {missing}"
