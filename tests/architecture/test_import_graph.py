"""The package's import graph, read from the source with ``ast`` (nothing is imported):

- no import cycle between modules of ``app`` (module-level imports; an import inside a function
  or under ``if TYPE_CHECKING:`` runs later or never and is not an edge);
- the layers: the numeric core imports nothing from the runtime, the adapters or web/GUI
  libraries, ``app.geometry`` imports nothing above it, no pools/progress bars/plots in geometry;
- the runtime (``app.service``) imports no web framework and nothing of the web adapter, and
  what imports a web framework totals at most :data:`WEB_LINES_MAX` lines;
- no ``from app.x import _private`` across modules (ruff's SLF001 covers ``obj._private``).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

APP = Path(__file__).resolve().parents[2] / "app"

CORE = (
    "app.vision",
    "app.geometry",
    "app.control",
    "app.sim",
    "app.streams",
    "app.calibration",
    "app.model",
)
RUNTIME = "app.service"
ADAPTERS = ("app.server", "app.viz", "app.cli")
WEB_FRAMEWORKS = ("fastapi", "starlette", "uvicorn")
WEB_GUI = (*WEB_FRAMEWORKS, "viser", "websockets", "httpx", "playwright")
#: the most lines the modules of ``app`` that import a web framework may total (issue 34)
WEB_LINES_MAX = 2500


def module_name(path: Path) -> str:
    rel = path.relative_to(APP.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute name of an import (the package uses absolute imports only)."""
    assert not node.level, f"{module}:{node.lineno}: relative import; use the absolute name"
    return node.module or ""


def module_level_imports(module: str, tree: ast.Module) -> list[tuple[str, list[str], int]]:
    """(imported module, names imported from it, line) for the imports that run at import."""
    out: list[tuple[str, list[str], int]] = []

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.Import):
                out.extend((a.name, [], node.lineno) for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                out.append((_resolve(module, node), [a.name for a in node.names], node.lineno))
            elif isinstance(node, ast.If) and not _is_type_checking(node):
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for h in node.handlers:
                    visit(h.body)
                visit(node.orelse)
                visit(node.finalbody)

    visit(tree.body)
    return out


def all_imports(module: str, tree: ast.Module) -> list[tuple[str, list[str], int]]:
    """Every import statement in the module, wherever it stands."""
    out: list[tuple[str, list[str], int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((a.name, [], node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            out.append((_resolve(module, node), [a.name for a in node.names], node.lineno))
    return out


def _load() -> dict[str, ast.Module]:
    return {
        module_name(p): ast.parse(p.read_text(), str(p))
        for p in sorted(APP.rglob("*.py"))
        if "__pycache__" not in p.parts
    }


MODULES = _load()


def _target(imported: str, names: list[str]) -> list[str]:
    """The app modules an import statement loads (``from app.x import y`` loads app.x.y when
    y is a submodule)."""
    out = []
    if imported in MODULES:
        out.append(imported)
    for n in names:
        sub = f"{imported}.{n}"
        if sub in MODULES:
            out.append(sub)
    # importing app.a.b runs app/__init__ and app/a/__init__ too
    parts = imported.split(".")
    for i in range(1, len(parts)):
        parent = ".".join(parts[:i])
        if parent in MODULES:
            out.append(parent)
    return out


def graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = {m: set() for m in MODULES}
    for m, tree in MODULES.items():
        for imported, names, _ in module_level_imports(m, tree):
            for t in _target(imported, names):
                # a package's own __init__ runs before its modules (it is never waited on)
                if t != m and not m.startswith(t + "."):
                    g[m].add(t)
    return g


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the directed graph, or None (iterative DFS with colours)."""
    colour = dict.fromkeys(g, 0)
    for root in sorted(g):
        if colour[root]:
            continue
        stack = [(root, iter(sorted(g[root])))]
        path = [root]
        colour[root] = 1
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
                continue
            if colour[nxt] == 1:
                return [*path[path.index(nxt) :], nxt]
            if colour[nxt] == 0:
                colour[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(g[nxt]))))
    return None


def test_the_graph_is_read() -> None:
    g = graph()
    assert len(g) > 100
    assert "app.vision.matching" in g["app.vision.pipeline"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle() -> None:
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " → ".join(cycle or [])


def _starts(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


@pytest.mark.parametrize("package", CORE)
def test_the_core_imports_no_adapter_and_no_web_or_gui_library(package: str) -> None:
    assert package in MODULES, f"{package} is not a package"
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, (package,))
        for imported, _, line in all_imports(m, tree)
        if _starts(imported, (RUNTIME, *ADAPTERS, *WEB_GUI))
    ]
    assert not bad, bad


def test_the_runtime_imports_no_web_framework_and_nothing_of_the_web_adapter() -> None:
    """``app.service`` (the producers, the tick loop, the bus, recordings, outputs) runs
    without FastAPI, Starlette or uvicorn: no import of them or of ``app.server`` anywhere in
    its modules (in a function or under ``if TYPE_CHECKING:`` too)."""
    assert RUNTIME in MODULES, f"{RUNTIME} is not a package"
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, (RUNTIME,))
        for imported, _, line in all_imports(m, tree)
        if _starts(imported, ("app.server", *WEB_FRAMEWORKS))
    ]
    assert not bad, bad


def web_modules() -> dict[str, int]:
    """The modules of ``app`` that import FastAPI, Starlette or uvicorn anywhere (a function or
    ``if TYPE_CHECKING:`` included) → their length in lines."""
    out = {}
    for path in sorted(APP.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        m = module_name(path)
        if any(_starts(i, WEB_FRAMEWORKS) for i, _, _ in all_imports(m, MODULES[m])):
            out[m] = len(path.read_text().splitlines())
    return out


def test_the_web_adapter_is_small() -> None:
    """Everything in ``app`` that imports a web framework totals at most 2,500 lines: the web
    adapter stays thin, the runtime below it does the work."""
    web = web_modules()
    assert "app.server.main" in web  # the measure sees the app
    assert "app.cli.serve" in web  # and the command that serves it
    assert not [m for m in web if _starts(m, (RUNTIME,))]
    total = sum(web.values())
    assert total <= WEB_LINES_MAX, (total, sorted(web.items(), key=lambda kv: -kv[1]))


def test_geometry_is_the_floor() -> None:
    above = ("app.calibration", "app.vision", "app.sim", "app.control", "app.streams")
    heavy = ("concurrent.futures", "multiprocessing", "tqdm", "matplotlib")
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, ("app.geometry",))
        for imported, _, line in all_imports(m, tree)
        if _starts(imported, above + heavy)
    ]
    assert not bad, bad


def test_control_knows_nothing_of_the_simulation() -> None:
    """The controller and the guidance's models (app.control) import nothing of the simulator
    (app.sim): what the guidance knows of the drogue is its own nominal model
    (app.model.drogue), never the simulated drogue's parameters."""
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, ("app.control",))
        for imported, _, line in all_imports(m, tree)
        if _starts(imported, ("app.sim",))
    ]
    assert not bad, bad


def test_the_guidance_reads_no_simulated_drogue_parameters() -> None:
    """The docking guidance (app.sim.docking.guidance) imports no hose–drogue simulator and
    takes the guidance's own model, not ``HoseDrogueParams``."""
    tree = MODULES["app.sim.docking.guidance"]
    imported = [i for i, _, _ in all_imports("app.sim.docking.guidance", tree)]
    assert not [i for i in imported if _starts(i, ("app.sim.hose_drogue",))]
    assert "HoseDrogueParams" not in ast.unparse(tree)


def test_no_private_name_is_imported_from_another_module() -> None:
    bad = [
        f"{m}:{line} imports {n} from {imported}"
        for m, tree in MODULES.items()
        for imported, names, line in all_imports(m, tree)
        if imported.startswith("app") and imported != m
        for n in names
        if n.startswith("_") and not n.startswith("__")
    ]
    assert not bad, bad


def test_viz_imports_nothing_of_the_server_not_even_for_type_checking() -> None:
    """The 3-D scene (app.viz) is handed its records and actions: it imports no module of the
    web layer, not even under ``if TYPE_CHECKING:`` (the records it draws live in app.model)."""
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, ("app.viz",))
        for imported, _, line in all_imports(m, tree)
        if _starts(imported, ("app.server", "app.cli"))
    ]
    assert not bad, bad


#: what the domain model may import besides the standard library
MODEL_ALLOWED = ("app.types", "app.model", "numpy", "pydantic")


def test_the_model_is_the_bottom() -> None:
    """The domain model (app.model: the tick record and its parts, the rig mount, the drogue
    model, the stereo frame) imports nothing of the package but app.types, and no library but
    numpy and pydantic: every other package imports it downward."""
    assert "app.model" in MODULES, "app.model is not a package"
    stdlib = sys.stdlib_module_names
    bad = [
        f"{m}:{line} imports {imported}"
        for m, tree in MODULES.items()
        if _starts(m, ("app.model",))
        for imported, _, line in all_imports(m, tree)
        if not _starts(imported, MODEL_ALLOWED) and imported.split(".")[0] not in stdlib
    ]
    assert not bad, bad


def test_no_two_public_classes_share_a_name() -> None:
    """One name per concept: a public class name is defined in one module only (two
    ``GuidanceConfig`` or two ``Blob`` read as one thing and are not)."""
    homes: dict[str, list[str]] = {}
    for m, tree in MODULES.items():
        for node in tree.body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                homes.setdefault(node.name, []).append(m)
    twice = {name: ms for name, ms in homes.items() if len(ms) > 1}
    assert not twice, twice


@pytest.mark.parametrize("name", ["decode_image", "default_mount"])
def test_one_function_per_concept(name: str) -> None:
    """The image decoder and the rig's default mount have one home each (a second function
    of the same name that does something else — raise an HTTP error, return another type —
    reads as the same thing)."""
    homes = [
        m
        for m, tree in MODULES.items()
        for node in tree.body
        if isinstance(node, ast.FunctionDef) and node.name == name
    ]
    assert len(homes) == 1, homes
