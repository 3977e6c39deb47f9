"""Function length (issue 34): no function of the package is over 120 lines outside the
compiled ``*_kernels.py`` modules — a long function is split into phases, each a function or
method handing a small frozen record to the next (as PX4's PositionControl):
``DockingSimulation.step`` (sense → guide → control → propagate/contact),
``NavigationPipeline._solve`` (match → triangulate → ring → ids → bound),
``render_pair`` (project → distractors → compose → truth) and
``calibrate_from_detections`` (cameras → rig check → joint fit → final estimate → report)."""

from __future__ import annotations

import ast
from pathlib import Path

APP = Path(__file__).resolve().parents[2] / "app"
LIMIT_LINES = 120


def function_lengths(source: str, filename: str) -> dict[str, int]:
    """Lines (``end_lineno - lineno + 1``, decorators excluded) of every function and method
    in ``source``, by qualified name (``Class.method``, ``outer.inner``)."""
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                out[name] = (child.end_lineno or child.lineno) - child.lineno + 1
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source, filename), "")
    return out


def long_functions() -> dict[str, int]:
    """``module path:qualified name`` → lines, for every function over the limit."""
    out = {}
    for path in sorted(APP.rglob("*.py")):
        if path.name.endswith("_kernels.py") or "__pycache__" in path.parts:
            continue
        rel = path.relative_to(APP.parent).as_posix()
        for name, n in function_lengths(path.read_text(), str(path)).items():
            if n > LIMIT_LINES:
                out[f"{rel}:{name}"] = n
    return out


def test_the_measure_counts_nested_functions_and_methods() -> None:
    src = "class A:\n    def m(self):\n        def inner():\n            pass\n\n        return 1\n"
    assert function_lengths(src, "<test>") == {"A.m": 5, "A.m.inner": 2}
    long_body = "def f():\n" + "    x = 1\n" * LIMIT_LINES
    assert function_lengths(long_body, "<test>") == {"f": LIMIT_LINES + 1}


def test_no_function_over_the_limit() -> None:
    assert len(list(APP.rglob("*.py"))) > 100, "the package was not found"
    long = long_functions()
    assert not long, f"functions over {LIMIT_LINES} lines (split them into phases): {long}"


def test_the_docking_step_runs_in_phases() -> None:
    tree = ast.parse((APP / "sim/docking/simulation.py").read_text())
    methods = {
        n.name: (n.end_lineno or n.lineno) - n.lineno + 1
        for n in ast.walk(tree)
        if isinstance(n, ast.FunctionDef)
    }
    for phase in ("step", "_sense", "_guide", "_control", "_propagate_and_check"):
        assert phase in methods and methods[phase] <= LIMIT_LINES, (phase, methods.get(phase))
    assert methods["step"] <= 20  # the tick reads as its phases
