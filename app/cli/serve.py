"""``aar-dock serve``: the FastAPI service (one uvicorn worker) + viser scene + tick loop."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import signal
import sys
from typing import TYPE_CHECKING, Any

from app.cli.drogue_options import add_drogue_options

if TYPE_CHECKING:
    import uvicorn

    from app.server.server_limits import ServerLimits
    from app.service.settings import Settings

PROXY_CONFIG = "deploy/nginx/nginx.conf.template"


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
    from app.service.settings import Settings

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
    if settings.push_port and not _port_free(settings.host, settings.push_port):
        print(
            f"aar-dock serve: push port {settings.push_port} on {settings.host} is in use",
            file=sys.stderr,
        )
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
    from app.server.main import create_app
    from app.server.server_limits import mark_guarded, server_limits
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
        f"viser on port {settings.viser_port if settings.viser_enabled else 'off'}"
        + (f", push WebSocket on port {settings.push_port}" if settings.push_port else ""),
        flush=True,
    )
    push_port = settings.push_port
    main_limits = server_limits(settings, push_listener=push_port is None)
    mark_guarded(app, main_limits)  # else the app warns, and /healthz says degraded
    server = uvicorn.Server(uvicorn_config(app, settings, settings.port, main_limits, "on"))
    log_hygiene.install()  # after uvicorn configured its loggers
    # uvicorn shuts down gracefully on SIGTERM, then restores the handler it found and raises
    # the signal again: with Python's default one the process would die there without its
    # exit handlers (multiprocessing's among them: the upload pool's semaphores then show as
    # "leaked" in the resource tracker). Found, it ends the process as a normal exit.
    signal.signal(signal.SIGTERM, exit_after_shutdown)
    if push_port is None:
        server.run()
    else:  # the push route's large messages on a listener of its own (the proxy routes it)
        push = uvicorn_config(app, settings, push_port, server_limits(settings), "off")
        with contextlib.suppress(KeyboardInterrupt):  # uvicorn re-raises the Ctrl-C it handled
            asyncio.run(serve_both(server, uvicorn.Server(push)))
    # uvicorn exits with started=False when the lifespan failed (e.g. viser port taken)
    return 0 if server.started else 1


def uvicorn_config(
    app: Any, settings: Settings, port: int, limits: ServerLimits, lifespan: str
) -> uvicorn.Config:
    """One listener of the app, with uvicorn's own limits (``server_limits``)."""
    import uvicorn

    return uvicorn.Config(
        app,
        host=settings.host,
        port=port,
        workers=1,
        log_level=settings.log_level,
        lifespan=lifespan,  # type: ignore[arg-type]
        limit_concurrency=limits.limit_concurrency,
        backlog=limits.backlog,
        ws=limits.ws_implementation,  # the one with backpressure (server_limits)
        ws_max_queue=limits.ws_max_queue,
        ws_max_size=limits.ws_max_size_bytes,  # refused at the frame header (1009)
        # no per-message compression: deflating every telemetry message once per client was
        # the web process's largest user of the GIL with 50 clients (benchmarks/bench_load.py)
        ws_per_message_deflate=False,
        timeout_keep_alive=limits.timeout_keep_alive_s,
        h11_max_incomplete_event_size=limits.h11_max_incomplete_event_size_bytes,
    )


def exit_after_shutdown(signum: int, frame: object) -> None:
    """The SIGTERM handler uvicorn finds and calls again after its graceful shutdown (or a
    SIGTERM before uvicorn listens): exit with status 0 through Python's exit handlers."""
    raise SystemExit(0)


async def serve_both(main: uvicorn.Server, push: uvicorn.Server) -> None:
    """The main listener (which runs the app's lifespan) and, once it has started, the push
    listener, in one event loop; when either stops, the other does."""
    main_task = asyncio.create_task(main.serve())
    while not main.started and not main_task.done():
        await asyncio.sleep(0.05)
    if main_task.done():
        return
    push_task = asyncio.create_task(push.serve())
    await asyncio.wait({main_task, push_task}, return_when=asyncio.FIRST_COMPLETED)
    main.should_exit = push.should_exit = True
    await asyncio.gather(main_task, push_task, return_exceptions=True)
