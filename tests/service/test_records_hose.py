"""The flown hose (``DockingTick.hose``) reaches the published record and its JSON (the
telemetry WebSocket and the MCAP ``/telemetry`` channel) through the simulation worker's pipe."""

from __future__ import annotations

import json
import math
import multiprocessing
from dataclasses import replace

import numpy as np

from app.model.tick import TickRecord
from app.service import records
from app.service.sim_worker.proxy import ProcessTick
from app.service.telemetry import STREAM_EXCLUDE
from app.sim.docking import DockingConfig, DockingSimulation, HoseState


def _published(tick_state: object) -> TickRecord:
    parent, child = multiprocessing.Pipe(duplex=True)
    try:
        child.send(tick_state)  # pickled whole, as the worker sends its tick
        state = parent.recv()
    finally:
        parent.close()
        child.close()
    raw = ProcessTick(
        state,
        None,
        None,
        None,
        None,
        1.0,
        deadline_s=0.0,
        released_s=0.0,
        received_s=None,
        missed_deadlines=0,
    )
    t = records.from_sim(raw.state, step_ms=1.0, raw=raw)
    return records.to_record(t, seq=0, clock_s=0.0, run=1)


def test_the_multibody_hose_reaches_the_record_and_its_json() -> None:
    sim = DockingSimulation(DockingConfig(vision=False, hose_model="multibody"))
    tick = sim.step()
    assert isinstance(tick.hose, HoseState)
    rec = _published(tick)
    assert rec.hose is not None
    np.testing.assert_allclose(rec.hose.nodes_m, sim.drogue.hose_nodes_m())
    np.testing.assert_allclose(rec.hose.nodes_m[-1], rec.drogue_truth_m)
    assert rec.hose.tension_n is not None and rec.hose.tension_n > 1000.0
    assert rec.hose.payout_m == 15.0 and rec.hose.contact_peak_tension_n is None
    sent = json.loads(rec.model_dump_json(exclude=STREAM_EXCLUDE))
    assert len(sent["hose"]["nodes_m"]) == 21 and sent["hose"]["contact_peak_tension_n"] is None


def test_the_reduced_hose_has_nodes_only_and_nan_is_none() -> None:
    sim = DockingSimulation(DockingConfig(vision=False))
    tick = sim.step()
    rec = _published(tick)
    assert rec.hose is not None and len(rec.hose.nodes_m) == 17
    np.testing.assert_allclose(rec.hose.nodes_m, sim.drogue.hose_nodes_m())
    assert rec.hose.tension_n is None and rec.hose.payout_m is None
    odd = HoseState(nodes_m=np.zeros((3, 3)), tension_n=math.nan, payout_m=14.0)
    rec = _published(replace(tick, hose=odd))
    assert rec.hose is not None and rec.hose.tension_n is None and rec.hose.payout_m == 14.0
