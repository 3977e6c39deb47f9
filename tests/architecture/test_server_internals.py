"""No module of ``app`` reaches into a web server's or a web library's internals (issue 34
item 4): the service uses uvicorn through ``uvicorn.Config``/``uvicorn.Server`` and its
documented settings, Starlette and the WebSocket libraries through their public modules.

Read from the source with ``ast`` (nothing is imported); every import statement counts,
wherever it stands (inside a function or under ``TYPE_CHECKING`` too), and so does an
attribute chain such as ``uvicorn.protocols.http``.
"""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
MODULES = {
    ".".join(p.relative_to(APP.parent).with_suffix("").parts): ast.parse(p.read_text(), str(p))
    for p in sorted(APP.rglob("*.py"))
    if "__pycache__" not in p.parts
}


def all_imports(tree: ast.Module) -> list[tuple[str, list[str], int]]:
    """(module, names imported from it, line) of every import statement, wherever it stands
    (the package uses absolute imports only)."""
    out: list[tuple[str, list[str], int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((a.name, [], node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            out.append((node.module or "", [a.name for a in node.names], node.lineno))
    return out


LIBRARIES = ("uvicorn", "starlette", "h11", "websockets", "wsproto", "httptools")
# uvicorn's modules that are its machinery, not its API (its API: ``uvicorn.Config``,
# ``uvicorn.Server``, ``uvicorn.run``, the settings they take)
UVICORN_INTERNALS = (
    "uvicorn.protocols",
    "uvicorn.server",
    "uvicorn.lifespan",
    "uvicorn.loops",
    "uvicorn.supervisors",
    "uvicorn.middleware",
    "uvicorn._types",
)


def _library(name: str) -> bool:
    return name.split(".")[0] in LIBRARIES


def _internal(dotted: str) -> bool:
    """``dotted`` (a module, or a module plus a name imported from it) is an internal."""
    if any(dotted == m or dotted.startswith(m + ".") for m in UVICORN_INTERNALS):
        return True
    return any(part.startswith("_") for part in dotted.split(".")[1:])


def _attribute_chain(node: ast.Attribute) -> str | None:
    parts: list[str] = []
    cur: ast.expr = node
    while isinstance(cur, ast.Attribute):
        parts.append(cur.attr)
        cur = cur.value
    if not isinstance(cur, ast.Name):
        return None
    parts.append(cur.id)
    return ".".join(reversed(parts))


def violations(module: str, tree: ast.Module) -> list[str]:
    found = []
    for imported, names, line in all_imports(tree):
        if not _library(imported):
            continue
        for dotted in [imported] + [f"{imported}.{n}" for n in names]:
            if _internal(dotted):
                found.append(f"{module}:{line}: imports {dotted}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            chain = _attribute_chain(node)
            if chain and _library(chain) and _internal(chain):
                found.append(f"{module}:{node.lineno}: uses {chain}")
    return found


def test_the_checker_finds_what_it_looks_for() -> None:
    src = (
        "import uvicorn\n"
        "from uvicorn.protocols.http.h11_impl import H11Protocol\n"
        "from uvicorn.server import Server\n"
        "from starlette._utils import is_async_callable\n"
        "import websockets.legacy._x\n"
        "x = uvicorn.protocols.websockets\n"
        "from starlette.middleware.trustedhost import TrustedHostMiddleware\n"
        "from websockets.sync.client import connect\n"
        "config = uvicorn.Config\n"
    )
    found = violations("app.example", ast.parse(src))
    assert [f.split(": ", 1)[1] for f in found] == [
        "imports uvicorn.protocols.http.h11_impl",
        "imports uvicorn.protocols.http.h11_impl.H11Protocol",
        "imports uvicorn.server",
        "imports uvicorn.server.Server",
        "imports starlette._utils",
        "imports starlette._utils.is_async_callable",
        "imports websockets.legacy._x",
        "uses uvicorn.protocols.websockets",
        "uses uvicorn.protocols",
    ]


def test_no_module_imports_a_web_servers_internals() -> None:
    found = [v for m, tree in MODULES.items() for v in violations(m, tree)]
    assert not found, "\n".join(found)
