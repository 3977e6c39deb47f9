"""One execution path for the simulated stream (issue 34): the service builds its simulation
only in the worker (``app/service/sim_worker/worker.py``), the tick loop steps only the
worker's paced source, and no setting chooses another path; a test that wants the simulation
in its own process injects a launcher (``tests/support/inline_sim.py``) that runs the same
worker loop. Read from the source with ``ast`` (a comment or a string does not count)."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

from app.service.settings import Settings
from app.service.tick_loop import TickLoop

APP = Path(__file__).resolve().parents[2] / "app"
RUNTIME = ("service", "server")  # the producers' packages (the campaigns are batch jobs)
WORKER = APP / "service" / "sim_worker" / "worker.py"


def builds_a_simulation(source: str) -> list[int]:
    """Lines where ``DockingSimulation`` is called (built), under any import name."""
    tree = ast.parse(source)
    names = {"DockingSimulation"}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            names |= {a.asname for a in node.names if a.name == "DockingSimulation" and a.asname}
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            called = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
            if called in names:
                lines.append(node.lineno)
    return lines


def test_the_checker_finds_what_it_looks_for() -> None:
    src = (
        "from app.sim.docking import DockingSimulation as DS\n"
        "import app.sim.docking as d\n"
        "a = DS(cfg)\n"
        "b = d.DockingSimulation(cfg)\n"
        "c = DockingSimulationConfig()\n"
    )
    assert builds_a_simulation(src) == [3, 4]


def test_only_the_worker_builds_the_services_simulation() -> None:
    found = {
        str(path.relative_to(APP)): lines
        for pkg in RUNTIME
        for path in sorted((APP / pkg).rglob("*.py"))
        if (lines := builds_a_simulation(path.read_text()))
    }
    assert found == {str(WORKER.relative_to(APP)): found.get(str(WORKER.relative_to(APP)), [])}
    assert found.get(str(WORKER.relative_to(APP))), "the worker builds the simulation"


def test_the_tick_loop_has_no_default_and_no_setting_for_another_path() -> None:
    params = inspect.signature(TickLoop.__init__).parameters
    assert params["source_factory"].default is inspect.Parameter.empty
    assert not any("in_process" in name for name in Settings.model_fields)
