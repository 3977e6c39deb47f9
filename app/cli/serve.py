"""``aar-dock serve``: the FastAPI service (one uvicorn worker) + viser scene + tick loop."""

from __future__ import annotations

import argparse
import ipaddress
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from app.cli.drogue_options import add_drogue_options

if TYPE_CHECKING:
    from app.server.settings import Settings

MAX_HEADER_BYTES = 16 * 1024  # a request's headers (h11_max_incomplete_event_size)
PROXY_CONFIG = "deploy/nginx/nginx.conf.template"
WS_FRAME_OVERHEAD_BYTES = 4096  # above the push route's largest message, for the frame


@dataclass(frozen=True)
class ServerLimits:
    """uvicorn's own limits, as ``aar-dock serve`` passes them (``uvicorn.Config``)."""

    limit_concurrency: int  # connections or in-flight tasks; a request beyond them gets 503
    timeout_keep_alive_s: int  # idle keep-alive (AAR_KEEP_ALIVE_S)
    ws_max_size_bytes: int  # the largest WebSocket message of any route (push)
    h11_max_incomplete_event_size_bytes: int  # a request's headers


def server_limits(settings: Settings, max_connections: int) -> ServerLimits:
    """``max_connections``: the connection guard's total cap (``AAR_MAX_CONNECTIONS``, at most
    the descriptor limit minus ``AAR_FD_RESERVE``). uvicorn's ``limit_concurrency`` sits one
    above it: the guard makes room at its cap by closing the oldest connection still waiting
    for its headers (a 503 there would answer the operators, not the slowloris), and uvicorn
    holds the same cap with 503s should the guard ever be switched off."""
    return ServerLimits(
        limit_concurrency=max_connections + 1,
        timeout_keep_alive_s=max(1, round(settings.keep_alive_s)),
        ws_max_size_bytes=settings.push_limit_bytes + WS_FRAME_OVERHEAD_BYTES,
        h11_max_incomplete_event_size_bytes=MAX_HEADER_BYTES,
    )


def exposure_notice(host: str) -> str | None:
    """The line ``serve`` prints when it listens beyond this machine (None on loopback)."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return None
    try:
        if ipaddress.ip_address(name).is_loopback:
            return None
    except ValueError:
        pass  # a host name: not known to be loopback
    return (
        f"aar-dock: listening on {host}, beyond this machine: an exposed deployment runs "
        f"behind the proxy ({PROXY_CONFIG}; docs/service.md, 'Behind the proxy'; "
        "docker compose up does)"
    )


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "serve",
        help="run the live service (REST/WebSocket API, operators' page, 3-D scene)",
        description=(
            "Start the service with the simulated docking stream running. Settings come from "
            "AAR_* environment variables (AAR_HOST, AAR_PORT, AAR_VISER_PORT, AAR_TICK_HZ, "
            "AAR_TOKEN, AAR_CALIBRATION, AAR_MAX_UPLOAD_MB, AAR_RECORDINGS_DIR, ...); flags "
            "override them."
        ),
    )
    p.add_argument("--host", help="bind address (default 127.0.0.1, AAR_HOST)")
    p.add_argument("--port", type=int, help="HTTP port (default 8000, AAR_PORT)")
    p.add_argument("--viser-port", type=int, help="viser port, pinned (default 8080)")
    p.add_argument("--tick-hz", type=float, help="tick loop rate (default 30 Hz)")
    p.add_argument("--calibration", help="stereo calibration JSON (default: bundled paper rig)")
    p.add_argument("--recordings-dir", help="where recordings go (default: see AAR_RECORDINGS_DIR)")
    p.add_argument("--no-viser", action="store_true", help="do not start the 3-D scene server")
    p.add_argument("--no-sim", action="store_true", help="do not start the simulated stream")
    p.add_argument(
        "--source",
        help="frame source (AAR_SOURCE): sim (default), push, video:LEFT,RIGHT (two videos, "
        "folders or globs), video:DIR (a frame recording), camera:I,J, camera:I (side-by-side)",
    )
    p.add_argument("--max-skew-ms", type=float, help="left/right pairing tolerance (default 10)")
    p.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="read video sources as fast as they are processed (default: at their frame times)",
    )
    p.add_argument("--loop", action="store_true", help="restart a video source at its end")
    p.add_argument("--fps", type=float, help="frame rate of image folders without timestamps")
    p.add_argument(
        "--mavlink",
        metavar="udpout:HOST:PORT",
        help="send the navigation result as MAVLink 2 LANDING_TARGET (AAR_MAVLINK; "
        "docs/ecosystem.md)",
    )
    p.add_argument(
        "--mavlink-sim",
        action="store_true",
        help="also send the simulated stream's targets on MAVLink, for SITL (AAR_MAVLINK_SIM; "
        "marked target_num 255)",
    )
    p.add_argument(
        "--foxglove-port",
        type=int,
        help="live Foxglove WebSocket server on this port (AAR_FOXGLOVE_PORT; off by default; "
        "Host, Origin and AAR_TOKEN checked, connections capped: docs/service.md)",
    )
    p.add_argument("--foxglove-host", help="its interface (AAR_FOXGLOVE_HOST, 127.0.0.1)")
    add_drogue_options(  # AAR_DROGUE, AAR_RING_RADIUS_MM
        p, "AAR_DROGUE, else the paper's 75 mm ring (the simulation: a 24-inch basket)"
    )
    p.set_defaults(func=run)


def _port_free(host: str, port: int) -> bool:
    import socket

    if port == 0:
        return True
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def settings_from_args(args: argparse.Namespace) -> Any:
    """Environment (``AAR_*``) first, then the flags that were given override it."""
    from app.server.settings import Settings

    overrides: dict[str, Any] = {}
    for flag, key in (
        ("host", "host"),
        ("port", "port"),
        ("viser_port", "viser_port"),
        ("tick_hz", "tick_hz"),
        ("calibration", "calibration"),
        ("recordings_dir", "recordings_dir"),
        ("source", "source"),
        ("max_skew_ms", "stream_max_skew_ms"),
        ("fps", "stream_fps"),
        ("mavlink", "mavlink"),
        ("foxglove_port", "foxglove_port"),
        ("foxglove_host", "foxglove_host"),
        ("drogue", "drogue"),
        ("ring_radius_mm", "ring_radius_mm"),
    ):
        value = getattr(args, flag, None)
        if value is not None:
            overrides[key] = value
    if args.no_viser:
        overrides["viser_enabled"] = False
    if args.no_sim:
        overrides["sim_autostart"] = False
    if getattr(args, "as_fast_as_possible", False):
        overrides["stream_realtime"] = False
    if getattr(args, "loop", False):
        overrides["stream_loop"] = True
    if getattr(args, "mavlink_sim", False):
        overrides["mavlink_sim"] = True
    return Settings(**overrides)


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from app.geometry.calibration import CalibrationError, StereoCalibration
    from app.vision.drogue import DrogueProfileError

    try:
        settings = settings_from_args(args)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors()
        )
        print(f"aar-dock serve: invalid setting: {problems}", file=sys.stderr)
        return 2
    try:
        StereoCalibration.load(settings.calibration)
        drogue = settings.drogue_profile()
    except (CalibrationError, DrogueProfileError) as exc:
        print(f"aar-dock serve: {exc}", file=sys.stderr)
        return 2
    notice = exposure_notice(settings.host)
    if notice:
        print(notice, flush=True)
    print(f"aar-dock: drogue: {drogue.label}", flush=True)
    if settings.source.strip() not in ("", "sim", "push"):
        from app.streams.frames import SourceError
        from app.streams.sources import open_source, parse_source

        try:  # fail here, with the reason, rather than in the service's start-up
            open_source(parse_source(settings.source)).close()
        except SourceError as exc:
            print(f"aar-dock serve: --source: {exc}", file=sys.stderr)
            return 2
    if not _port_free(settings.host, settings.port):
        print(f"aar-dock serve: port {settings.port} on {settings.host} is in use", file=sys.stderr)
        return 2
    fg = settings.foxglove_port
    if fg and not _port_free(settings.foxglove_host, fg):
        print(
            f"aar-dock serve: Foxglove port {fg} on {settings.foxglove_host} is in use",
            file=sys.stderr,
        )
        return 2
    if settings.viser_enabled and not _port_free(settings.viser_bind_host, settings.viser_port):
        print(
            f"aar-dock serve: viser port {settings.viser_port} is in use "
            "(choose another with --viser-port or AAR_VISER_PORT)",
            file=sys.stderr,
        )
        return 2

    import uvicorn

    from app.server import log_hygiene
    from app.server.connection_guard import (
        guarded_listener,
        mark_guarded,
        new_registry,
        protocol_classes,
    )
    from app.server.main import PUSH_PATH, create_app
    from app.sim.warmup import compile_kernels

    # the navigation core's compiled loops: compiled once per install and cached on disk;
    # done here so that the first ticks (in the worker) do not wait for the compiler
    print(
        "aar-dock: preparing the navigation kernels (first run after install: ~1 min)", flush=True
    )
    compile_kernels()

    app = create_app(settings)
    print(
        f"aar-dock: http://{settings.host}:{settings.port}/ (API docs /docs), "
        f"viser on port {settings.viser_port if settings.viser_enabled else 'off'}",
        flush=True,
    )
    # connection caps, header timeout (slowloris), per-route WebSocket message sizes and
    # rates, enforced in uvicorn's protocol layer (app.server.connection_guard)
    registry = new_registry(settings, PUSH_PATH)
    http_protocol, ws_protocol = protocol_classes(registry)
    mark_guarded(app, registry)  # else the app warns, and /healthz says degraded
    limits = server_limits(settings, registry.policy.max_connections)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        workers=1,
        log_level=settings.log_level,
        http=http_protocol,
        ws=ws_protocol,
        limit_concurrency=limits.limit_concurrency,
        # the largest message of any route (push); each connection gets its route's limit
        ws_max_size=limits.ws_max_size_bytes,
        # no per-message compression: deflating every telemetry message once per client was
        # the web process's largest user of the GIL with 50 clients (benchmarks/bench_load.py)
        ws_per_message_deflate=False,
        timeout_keep_alive=limits.timeout_keep_alive_s,
        h11_max_incomplete_event_size=limits.h11_max_incomplete_event_size_bytes,
    )
    log_hygiene.install()  # after uvicorn configured its loggers
    server = uvicorn.Server(config)
    # the listening socket stops accepting short of the descriptor limit (connection_guard)
    server.run(sockets=[guarded_listener(config.bind_socket(), registry)])
    # uvicorn exits with started=False when the lifespan failed (e.g. viser port taken)
    return 0 if server.started else 1
