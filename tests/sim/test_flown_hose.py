"""The flown drogue carries the run's draw; the guidance's model never does."""

from __future__ import annotations

import pytest

from app.sim.docking import DockingConfig
from app.sim.docking.flown_hose import flown_drogue, nominal_drogue_model
from app.sim.hose_drogue import HoseDrogue
from app.sim.imperfections import HARSH, NONE, draw


def test_flown_drogue_scales_the_nominal_set_and_the_model_ignores_the_draw() -> None:
    cfg = DockingConfig()
    d = draw(HARSH, 17)
    flown_hose = flown_drogue(cfg, 0.77, 147.5, d, 0.02)
    assert isinstance(flown_hose, HoseDrogue)  # the default: the reduced-order model
    flown = flown_hose.params
    nominal_hose = flown_drogue(cfg, 0.77, 147.5, draw(NONE, 17), 0.02)
    assert isinstance(nominal_hose, HoseDrogue)
    nominal = nominal_hose.params
    assert flown.hose_length_m == pytest.approx(nominal.hose_length_m * d.hose_scale["hose_length"])
    assert flown.drogue_cd == pytest.approx(nominal.drogue_cd * d.hose_scale["drogue_drag"])
    assert flown.bow_force_n == pytest.approx(cfg.bow_wave_force_n * d.bow_scale)
    model = nominal_drogue_model(cfg, 0.77, 147.5)
    assert model.omega_rad_s == pytest.approx(nominal.omega_rad_s)
    assert model.bow_force_n == cfg.bow_wave_force_n
    assert model.rest_m == pytest.approx(tuple(nominal.equilibrium_m()))
