"""One execution path for uploads (issue 34): ``POST /stereo`` hands ``process_upload`` to the
``UploadPool`` and nothing else of the route runs work off the event loop; a test that wants the
work in its own process injects an executor (``create_app(upload_executor=...)``) rather than
take another path. Read from the source with ``ast`` (a comment or a string does not count)."""

from __future__ import annotations

import ast
from pathlib import Path

ROUTE = Path(__file__).resolve().parents[2] / "app" / "server" / "routers" / "stereo.py"
# the ways a coroutine hands work to a thread or a process besides the upload pool
OFF_LOOP = {"to_thread", "run_in_executor", "run_in_threadpool", "submit", "map"}


def _called(node: ast.Call) -> str | None:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)


def off_loop_calls(source: str) -> tuple[list[str], list[str]]:
    """(what the pool's ``run`` calls are given first, other off-loop calls), each as
    ``name:line``."""
    runs: list[str] = []
    others: list[str] = []
    calls = [n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Call)]
    for node in sorted(calls, key=lambda n: (n.lineno, n.col_offset)):
        called = _called(node)
        if called == "run" and node.args:
            first = node.args[0]
            name = first.id if isinstance(first, ast.Name) else ast.unparse(first)
            runs.append(f"{name}:{node.lineno}")
        elif called in OFF_LOOP:
            others.append(f"{called}:{node.lineno}")
    return runs, others


def test_the_checker_finds_what_it_looks_for() -> None:
    two_paths = (
        "async def f(state, pool):\n"
        "    await pool.run(process_upload, 1)\n"
        "    await asyncio.to_thread(decode, 2)\n"
        "    state.loop.run(other)\n"
    )
    runs, others = off_loop_calls(two_paths)
    assert runs == ["process_upload:2", "other:4"] and others == ["to_thread:3"]


def test_the_upload_route_has_one_execution_path() -> None:
    runs, others = off_loop_calls(ROUTE.read_text())
    assert [r.split(":")[0] for r in runs] == ["process_upload"], runs
    assert not others, f"work sent off the event loop besides the upload pool: {others}"
