"""Reads: ``/state``, ``/history``, ``/healthz``, ``/metrics``, ``/config``, ``/scene/view``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request, status
from fastapi.responses import PlainTextResponse
from pydantic import BaseModel, Field

from app.model.tick import TickRecord
from app.server.dependencies import StateDep
from app.server.schemas import (
    DrogueInfo,
    FoxgloveHealth,
    Health,
    HealthComponent,
    Message,
    ServiceConfig,
)
from app.server.security import in_process
from app.server.server_limits import UNGUARDED, is_guarded
from app.service import guard_events
from app.service.metrics import render_metrics

router = APIRouter(tags=["state"])


@router.get("/state", response_model=TickRecord, responses={404: {"model": Message}})
def get_latest(state: StateDep) -> TickRecord:
    """The latest published tick record (simulated tick or upload)."""
    latest = state.bus.latest
    if latest is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "no tick published yet")
    return latest


@router.get("/history", response_model=list[TickRecord])
def get_history(
    state: StateDep,
    seconds: Annotated[
        float,
        Query(gt=0.0, allow_inf_nan=False, description="how far back (s), at most AAR_HISTORY_S"),
    ] = 10.0,
) -> list[TickRecord]:
    """Tick records of the last ``seconds`` from the bounded ring buffer (oldest first)."""
    if seconds > state.settings.history_s:
        raise HTTPException(
            422,
            f"seconds must be <= {state.settings.history_s:g} (the ring buffer length)",
        )
    return state.bus.history(seconds)


def _guard_component(request: Request) -> HealthComponent | None:
    """A real client's view: does the server run with ``aar-dock serve``'s limits?"""
    if in_process(request.scope, request.headers):
        return None  # in-process test clients: no server, no connections to guard
    if is_guarded(request.app):
        return HealthComponent(name="server_limits", status="ok")
    return HealthComponent(name="server_limits", status="degraded", reason=UNGUARDED)


@router.get("/healthz", response_model=Health)
def healthz(state: StateDep, request: Request) -> Health:
    """``ok`` or ``degraded``; ``components`` names what is degraded and why."""
    loop = state.loop
    now = loop.clock.now()
    age = None if loop.last_tick_clock is None else max(0.0, now - loop.last_tick_clock)
    alive = loop.alive
    ok = alive and (not loop.running or loop.done or (age is not None and age < 5.0))
    loop_reason = None
    if not alive:
        loop_reason = "the tick loop thread is not running"
    elif not ok:
        loop_reason = f"no tick for {age if age is not None else 0:.1f} s"
    components = [
        HealthComponent(name="tick_loop", status="ok" if ok else "degraded", reason=loop_reason)
    ]
    stream = state.streams.health() if state.streams is not None else None
    rate = loop.tick_rate_hz() if loop.running else 0.0
    source = "sim"
    if stream is not None:
        source, rate = stream.source, stream.rate_hz
        components.append(
            HealthComponent(
                name=f"stream:{stream.source}", status=stream.status, reason=stream.reason
            )
        )
    if state.mavlink is not None:
        why = state.mavlink.health()
        components.append(
            HealthComponent(name="mavlink", status="degraded" if why else "ok", reason=why)
        )
    foxglove = None
    if state.foxglove is not None:
        gate = state.foxglove.health()
        foxglove = FoxgloveHealth(
            running=gate.running,
            port=gate.port,
            clients=gate.clients,
            handshakes=gate.handshakes,
            served=gate.served,
            refused=gate.refused,
        )
        why = None if gate.running else "the Foxglove port's gate is not running"
        components.append(
            HealthComponent(name="foxglove", status="degraded" if why else "ok", reason=why)
        )
    guard = _guard_component(request)
    if guard is not None:
        components.append(guard)
    degraded = any(c.status != "ok" for c in components)
    return Health(
        status="degraded" if degraded else "ok",
        source=source,
        components=components,
        loop_alive=alive,
        sim_running=loop.running,
        tick_hz_target=loop.config.tick_hz,
        tick_rate_hz=round(rate, 3),
        last_tick_age_s=None if age is None else round(age, 4),
        ticks=loop.ticks,
        dropped_ticks=loop.dropped,
        errors=loop.errors,
        last_error=loop.last_error,
        viser=state.viz is not None,
        drogue=None if state.streams is None else DrogueInfo.of(state.streams.drogue_in_use()),
        configured_drogue=DrogueInfo.of(state.uploads.drogue),
        foxglove=foxglove,
    )


@router.get("/metrics", response_class=PlainTextResponse)
def metrics(state: StateDep) -> PlainTextResponse:
    """Prometheus text format: tick rate, dropped ticks, stage latencies."""
    text = render_metrics(
        state.loop,
        state.bus,
        ws_clients=state.hub.client_count,
        uploads=state.uploads.count,
        sim_worker_restarts=None if state.sim_worker is None else state.sim_worker.restarts,
        upload_pool_restarts=state.upload_pool.restarts,
        streams=state.streams,
        guard_counters=guard_events.snapshot(),
    )
    return PlainTextResponse(text, media_type="text/plain; version=0.0.4; charset=utf-8")


@router.get("/config", response_model=ServiceConfig)
def service_config(request: Request, state: StateDep) -> ServiceConfig:
    """What the operators' page needs: where the viser client is, limits, tick rate."""
    url = state.settings.public_viser_url
    if url is None and state.viser_port is not None:
        host = request.url.hostname or "127.0.0.1"
        url = f"{request.url.scheme}://{host}:{state.viser_port}/"
    return ServiceConfig(
        viser_port=state.viser_port,
        viser_url=url,
        tick_hz=state.loop.config.tick_hz,
        token_required=bool(state.settings.token),
        max_upload_mb=state.settings.max_upload_mb,
        image_size=state.calibrations.current.image_size,
    )


class ClientView(BaseModel):
    """One 3-D view's camera as its browser reports it (tanker frame, m; rad; px)."""

    client_id: int
    position: list[float]
    look_at: list[float]
    up: list[float]
    fov_rad: float = Field(description="vertical field of view (rad)")
    width_px: int
    height_px: int
    panel_minimized: bool = Field(description="the control panel was minimized (embedded view)")


class SceneView(BaseModel):
    targets_m: list[list[float]] = Field(
        description="points kept in view: drogue centre and rim, probe tip, receiver (m)"
    )
    clients: list[ClientView]


@router.get("/scene/view", response_model=SceneView)
def scene_view(state: StateDep) -> SceneView:
    """The 3-D views' cameras and the docking points they frame (empty without viser)."""
    viz = state.viz
    if viz is None:
        return SceneView(targets_m=[], clients=[])
    clients = [ClientView(**v) for v in viz.views()]
    return SceneView(targets_m=viz.targets(), clients=clients)
