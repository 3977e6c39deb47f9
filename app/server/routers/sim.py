"""Simulation control: ``/sim/start``, ``/sim/stop``, ``/sim/reset``, ``/sim/config``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, HTTPException
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from app.server.dependencies import StateDep, require_token
from app.server.schemas import PlantInfo, SimConfig, SimConfigUpdate, SimStatus
from app.service.state import AppState

router = APIRouter(prefix="/sim", tags=["simulation"])


def plant_info(config: SimConfig) -> PlantInfo | None:
    """The configured plant's airframe and trim (its design is built once and cached)."""
    from app.service.sim_source import docking_config
    from app.sim.docking import describe_plant

    try:
        return PlantInfo.model_validate(describe_plant(docking_config(config)))
    except (RuntimeError, ValueError, ImportError):  # e.g. JSBSim unavailable on this machine
        return None


def _status(state: AppState) -> SimStatus:
    loop = state.loop
    return SimStatus(
        running=loop.running,
        run=loop.run,
        done=loop.done,
        config=loop.config,
        plant=plant_info(loop.config),
    )


@router.get("", response_model=SimStatus)
def sim_status(state: StateDep) -> SimStatus:
    return _status(state)


@router.post("/start", response_model=SimStatus, dependencies=[Depends(require_token)])
def sim_start(state: StateDep) -> SimStatus:
    state.loop.start_sim()
    return _status(state)


@router.post("/stop", response_model=SimStatus, dependencies=[Depends(require_token)])
def sim_stop(state: StateDep) -> SimStatus:
    state.loop.stop_sim()
    return _status(state)


@router.post("/reset", response_model=SimStatus, dependencies=[Depends(require_token)])
def sim_reset(state: StateDep) -> SimStatus:
    """A new run with the same configuration (and seed)."""
    state.loop.reset()
    if state.viz is not None:
        state.viz.on_reset()
    return _status(state)


@router.get("/config", response_model=SimConfig)
def get_sim_config(state: StateDep) -> SimConfig:
    return state.loop.config


@router.put("/config", response_model=SimConfig, dependencies=[Depends(require_token)])
def put_sim_config(update: Annotated[SimConfigUpdate, Body()], state: StateDep) -> SimConfig:
    """Partial update (omitted fields keep their value); ranges validated (422); new run."""
    merged = state.loop.config.model_dump()
    merged.update(update.model_dump(exclude_unset=True, exclude_none=True))
    try:
        config = SimConfig.model_validate(merged)
    except ValidationError as exc:
        raise RequestValidationError(
            [{**e, "loc": ("body", *e["loc"])} for e in exc.errors(include_url=False)]
        ) from None
    try:
        state.apply_sim_config(config)
    except (ValueError, TypeError) as exc:  # the simulation refused it: nothing changed
        raise HTTPException(422, f"simulation rejected the config: {exc}") from None
    return config
