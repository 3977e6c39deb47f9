"""Precise types in the runtime and the web modules (issue 34): ``app/service`` and
``app/server`` use ``Any`` at most :data:`ANY_MAX` times, so that what crosses a process pipe,
an HTTP body or a callback has a type that says what it is.

Read from the source with ``ast`` (nothing is imported): every name ``Any`` (``Any``,
``typing.Any``) counts wherever it stands — annotations, aliases, casts — and so does one in a
string annotation; a comment or another string does not. ``Any`` imported under another name
is refused outright (it would escape the count).
"""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
PACKAGES = ("service", "server")
#: the most ``Any`` the runtime and web modules may use together (issue 34)
ANY_MAX = 10


def _is_any(node: ast.AST) -> bool:
    return (isinstance(node, ast.Name) and node.id == "Any") or (
        isinstance(node, ast.Attribute) and node.attr == "Any"
    )


def _annotations(tree: ast.AST) -> list[ast.expr]:
    """Every annotation of ``tree`` (arguments, returns, annotated assignments)."""
    out: list[ast.expr | None] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.arg):
            out.append(node.annotation)
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            out.append(node.returns)
        elif isinstance(node, ast.AnnAssign):
            out.append(node.annotation)
    return [a for a in out if a is not None]


def any_uses(source: str, name: str = "<source>") -> list[int]:
    """The lines of ``source`` that use ``Any`` (once per use)."""
    tree = ast.parse(source, name)
    lines = [node.lineno for node in ast.walk(tree) if _is_any(node)]
    for annotation in _annotations(tree):  # "Any" and "dict[str, Any]" as strings
        for const in ast.walk(annotation):
            if isinstance(const, ast.Constant) and isinstance(const.value, str):
                try:
                    inner = ast.parse(const.value, mode="eval")
                except SyntaxError:
                    continue
                lines.extend(const.lineno for node in ast.walk(inner) if _is_any(node))
    return lines


def renamed_any(source: str) -> bool:
    """``from typing import Any as Something``: ``Any`` under a name the count would miss."""
    return any(
        isinstance(node, ast.ImportFrom)
        and any(a.name == "Any" and a.asname not in (None, "Any") for a in node.names)
        for node in ast.walk(ast.parse(source))
    )


def uses_by_module() -> dict[str, list[int]]:
    found: dict[str, list[int]] = {}
    for package in PACKAGES:
        for path in sorted((APP / package).rglob("*.py")):
            rel = str(path.relative_to(APP.parent))
            source = path.read_text()
            assert not renamed_any(source), f"{rel}: Any imported under another name"
            lines = any_uses(source, rel)
            if lines:
                found[rel] = lines
    return found


def test_the_count_sees_what_it_should() -> None:
    source = (
        "import typing\n"
        "from typing import Any  # Any in a comment does not count\n"
        "X = dict[str, Any]\n"
        "def f(a: 'Any', b: typing.Any) -> 'list[Any]':\n"
        "    '''Any in a docstring does not count'''\n"
        "    return [a, 'Any', b]\n"
    )
    assert sorted(any_uses(source)) == [3, 4, 4, 4]
    assert renamed_any("from typing import Any as A\n")
    assert not renamed_any("from typing import Any\n")


def test_the_runtime_and_web_modules_use_any_sparingly() -> None:
    found = uses_by_module()
    assert (APP / "service" / "sim_worker" / "wire.py").is_file()  # the count reads the tree
    total = sum(len(lines) for lines in found.values())
    assert total <= ANY_MAX, (total, found)
