"""viser GUI panel: simulation controls, live uPlot charts, status, camera images.

The charts, status and camera images are shared by every viewer. The simulation controls are
built per client (``client.gui``, inside the shared "Simulation" folder), so that each
browser tab has its own *locked*/*unlocked* state: with ``AAR_TOKEN`` set a tab sees them
disabled until it enters the operator token (see :mod:`app.viz.access`).

Every change from a client is checked on the server, whatever the browser shows: the client
must be allowed to control (:meth:`AccessPolicy.may_control`), the value must be of the
widget's type and inside the widget's range (:data:`LIMITS`), and the resulting configuration
must pass :class:`app.sim.sim_config.SimConfig` (the REST API's model). A refused change is
logged, not applied, and the client's widgets are re-synced to the real configuration.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Coroutine
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import viser
import viser.uplot as uplot

from app.model.frames import RawFrame
from app.model.tick import TickRecord
from app.sim.sim_config import LED_COUNT, TURBULENCE_LEVELS, SimConfig
from app.streams.annotations import Side, annotate
from app.viz.access import MAX_TOKEN_CHARS, AccessPolicy

log = logging.getLogger(__name__)
WINDOW = 300  # samples kept in each chart (fixed window)
TURBULENCE = TURBULENCE_LEVELS
XYZ_COLORS = ("#e04040", "#30a050", "#3070e0")
CTRL_COLORS = ("#444444", "#e08020", "#2090d0", "#a040c0")
# the widgets' ranges (tighter than SimConfig's: the GUI offers less than the REST API)
LIMITS: dict[str, tuple[float, float]] = {
    "closure_speed_mps": (0.2, 3.0),
    "noise_sigma": (0.0, 20.0),
    "clutter": (0, 20),
}
N_LEDS = LED_COUNT
BUTTONS = ("start", "stop", "reset")
LOCKED_NOTE = "**Read-only.** Enter the operator token (`AAR_TOKEN`) and press Unlock."
UNLOCKED_NOTE = "**Operator controls unlocked** for this browser tab."
STOPPED_NOTE = "**STOPPED** (the simulation is stopped: Start resumes it)"


# x: seconds since the start of the current run (not a date: "time": False)
T_AXES: tuple[Any, ...] = ({"label": "t since run start (s)"}, {})


def _series(label: str, color: str, dash: bool = False) -> uplot.Series:
    s: dict[str, Any] = {"label": label, "stroke": color, "width": 1.5}
    if dash:
        s["dash"] = (6.0, 4.0)
    return s  # type: ignore[return-value]


def well_typed(kind: str, value: object) -> bool:
    """Could the widget of this kind send ``value``? (type only: numbers finite, any range)"""
    if kind in BUTTONS or kind == "unlock" or kind.startswith("led"):
        return isinstance(value, bool)
    if kind == "turbulence":
        return isinstance(value, str)
    if kind == "token":
        return isinstance(value, str) and len(value) <= MAX_TOKEN_CHARS
    if kind in LIMITS:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        return math.isfinite(value) and (kind != "clutter" or float(value).is_integer())
    return False


def value_ok(kind: str, value: object) -> bool:
    """Is ``value`` a value the widget of this kind offers? (type and the widget's range)"""
    if not well_typed(kind, value):
        return False
    if kind == "turbulence":
        return value in TURBULENCE
    if kind in LIMITS:
        lo, hi = LIMITS[kind]
        return lo <= float(value) <= hi  # type: ignore[arg-type]
    return True


def _fit(name: str, value: float) -> float:
    lo, hi = LIMITS[name]
    return min(max(value, lo), hi)


def _slider(gui: Any, label: str, name: str, step: float, cfg: Any, locked: bool) -> Any:
    """A slider over ``LIMITS[name]``, starting at the config's value clamped into it (viser
    refuses an initial value outside the range)."""
    lo, hi = LIMITS[name]
    value = _fit(name, getattr(cfg, name))
    return gui.add_slider(
        label,
        min=lo,
        max=hi,
        step=step,
        initial_value=int(value) if isinstance(step, int) else value,
        disabled=locked,
    )


@dataclass
class ClientPanel:
    """One client's simulation controls (client-scoped viser handles)."""

    client_id: int
    turbulence: Any
    closure: Any
    noise: Any
    clutter: Any
    dropout: list[Any]
    buttons: dict[str, Any]
    note: Any = None
    token: Any = None
    unlock: Any = None
    kinds: dict[str, str] = field(default_factory=dict)  # widget uuid -> kind

    def inputs(self) -> dict[str, Any]:
        out = {"turbulence": self.turbulence, "closure_speed_mps": self.closure}
        out |= {"noise_sigma": self.noise, "clutter": self.clutter}
        out |= {f"led{i + 1}": h for i, h in enumerate(self.dropout)}
        return out

    def set_locked(self, locked: bool) -> None:
        for h in (*self.inputs().values(), *self.buttons.values()):
            h.disabled = locked
        if self.note is not None:
            self.note.content = LOCKED_NOTE if locked else UNLOCKED_NOTE
        for h in (self.token, self.unlock):
            if h is not None:
                h.visible = locked


def _uuid(handle: Any) -> str | None:
    impl = getattr(handle, "_impl", None)
    uuid = getattr(impl, "uuid", None)
    return uuid if isinstance(uuid, str) else None


class DockingGui:
    """Builds the panel once; :meth:`update` feeds charts/status; callbacks drive ``actions``.

    ``actions`` is the service state (:class:`app.service.state.AppState`): its ``loop``
    (start/stop/reset), ``apply_sim_config`` and ``settings.token``. ``policy`` says who may
    drive it (default: the token from ``actions.settings``, no Origin check).
    """

    def __init__(
        self, server: viser.ViserServer, actions: Any, *, policy: AccessPolicy | None = None
    ) -> None:
        self.server = server
        self.actions = actions
        if policy is None:
            policy = AccessPolicy(getattr(getattr(actions, "settings", None), "token", None))
        self.policy = policy
        gui = server.gui
        gui.configure_theme(control_width="medium")
        self.status = gui.add_markdown("**starting…**")
        self._buf: dict[str, deque[float]] = {}
        self._chart_run: int | None = None
        self._last_miss: tuple[float, bool, int] | None = None  # miss (m), captured, run
        self._panels: dict[int, ClientPanel] = {}
        self._panels_lock = threading.Lock()  # panel builds (one folder context at a time), sync
        # GUI changes run here, one at a time, in message order (read-modify-apply of the config)
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aar-viz-gui")
        self.rejected = 0  # refused GUI changes (tests, diagnostics)
        self._rejected_lock = threading.Lock()

        self.sim_folder = gui.add_folder("Simulation")
        with gui.add_folder("Charts"):
            t0 = np.zeros(2)
            self.plot_rel = gui.add_uplot(
                (t0,) * 7,
                (
                    {"label": "t (s)"},
                    _series("x meas", XYZ_COLORS[0]),
                    _series("y meas", XYZ_COLORS[1]),
                    _series("z meas", XYZ_COLORS[2]),
                    _series("x ref", XYZ_COLORS[0], dash=True),
                    _series("y ref", XYZ_COLORS[1], dash=True),
                    _series("z ref", XYZ_COLORS[2], dash=True),
                ),
                title="drogue − probe (m): measured vs reference",
                scales={"x": {"time": False}},
                axes=T_AXES,
                aspect=1.6,
            )
            self.plot_miss = gui.add_uplot(
                (t0,) * 3,
                (
                    {"label": "t (s)"},
                    _series("lateral miss (m)", "#d03030"),
                    _series("capture radius", "#30a050", dash=True),
                ),
                title="miss distance (m)",
                scales={"x": {"time": False}},
                axes=T_AXES,
                aspect=2.2,
            )
            self.plot_ctrl = gui.add_uplot(
                (t0,) * 5,
                (
                    {"label": "t (s)"},
                    _series("throttle", CTRL_COLORS[0]),
                    _series("aileron", CTRL_COLORS[1]),
                    _series("elevator", CTRL_COLORS[2]),
                    _series("rudder", CTRL_COLORS[3]),
                ),
                title="control deflections",
                scales={"x": {"time": False}},
                axes=T_AXES,
                aspect=2.0,
            )
        with gui.add_folder("Cameras"):
            blank = np.zeros((256, 320, 3), np.uint8)
            self.img_left = gui.add_image(blank, label="left", format="jpeg")
            self.img_right = gui.add_image(blank, label="right", format="jpeg")
        self._loop: asyncio.AbstractEventLoop | None = None  # viser's event loop
        server.on_client_connect(self._note_loop)
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    async def _note_loop(self, client: Any) -> None:
        self._loop = asyncio.get_running_loop()

    def _on_loop(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on viser's event loop and wait for it (at most 2 s).

        Widget values are written there, where viser applies incoming client updates: a
        re-sync written from another thread can interleave with an incoming update and leave
        the client showing its refused value (viser drops the re-sync message when the echo
        of the incoming update replaces it in the client's queue).
        """
        loop = self._loop
        if loop is None or loop.is_closed():
            fn()
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            fn()
            return

        async def run() -> None:
            fn()

        try:
            asyncio.run_coroutine_threadsafe(run(), loop).result(timeout=2.0)
        except TimeoutError:
            log.warning("viser: widget sync timed out (event loop busy or stopped)")

    # ---- per-client controls ----------------------------------------------------------
    def panel(self, client_id: int) -> ClientPanel | None:
        return self._panels.get(client_id)

    def _on_connect(self, client: Any) -> None:
        client_id = int(client.client_id)
        if self.policy.is_refused(client_id):
            return
        try:
            with self._panels_lock:
                panel = self._build_panel(client)
                self._panels[client_id] = panel
                self._sync_panel(panel, self.actions.loop.config)
        except Exception:
            log.exception("viser: building the controls of client %s failed", client_id)

    def _on_disconnect(self, client: Any) -> None:
        with self._panels_lock:
            self._panels.pop(int(client.client_id), None)

    def _build_panel(self, client: Any) -> ClientPanel:
        gui = client.gui
        cfg = self.actions.loop.config
        locked = not self.policy.may_control(int(client.client_id))
        note = token = unlock = None
        with self.sim_folder:
            if self.policy.token_required:
                note = gui.add_markdown(LOCKED_NOTE)
                token = gui.add_text("Operator token", initial_value="", hint="AAR_TOKEN")
                unlock = gui.add_button("Unlock", icon=viser.Icon.LOCK_OPEN)
            buttons = {
                "start": gui.add_button("Start", icon=viser.Icon.PLAYER_PLAY, disabled=locked),
                "stop": gui.add_button("Stop", icon=viser.Icon.PLAYER_STOP, disabled=locked),
                "reset": gui.add_button("Reset", icon=viser.Icon.REFRESH, disabled=locked),
            }
            panel = ClientPanel(
                client_id=int(client.client_id),
                turbulence=gui.add_dropdown(
                    "Turbulence", TURBULENCE, initial_value=cfg.turbulence, disabled=locked
                ),
                closure=_slider(gui, "Closure (m/s)", "closure_speed_mps", 0.1, cfg, locked),
                noise=_slider(gui, "Noise σ (DN)", "noise_sigma", 0.5, cfg, locked),
                clutter=_slider(gui, "Clutter lights", "clutter", 1, cfg, locked),
                dropout=[
                    gui.add_checkbox(
                        f"LED {i} off", initial_value=i in cfg.led_dropout, disabled=locked
                    )
                    for i in range(1, N_LEDS + 1)
                ],
                buttons=buttons,
                note=note,
                token=token,
                unlock=unlock,
            )
        if not locked and note is not None:
            panel.set_locked(False)
        widgets = {**panel.inputs(), **buttons, "token": token, "unlock": unlock}
        for kind, handle in widgets.items():
            uuid = _uuid(handle) if handle is not None else None
            if uuid is not None:
                panel.kinds[uuid] = kind
        for kind, handle in panel.inputs().items():
            handle.on_update(self._guarded(panel, kind))
        for kind, handle in buttons.items():
            handle.on_click(self._guarded(panel, kind))
        if unlock is not None:
            unlock.on_click(self._guarded(panel, "unlock"))
        return panel

    def _guarded(self, panel: ClientPanel, kind: str) -> Callable[[Any], Coroutine[Any, Any, None]]:
        """The viser callback of one widget.

        An ``async`` callback, so that viser runs it on its event loop right after it has taken
        the message: the value is read there, in message order, before a later message or a
        re-sync can change the widget; the work is queued, in that order, on one worker thread
        (never on the event loop: applying a config rebuilds the simulation).
        """

        async def callback(event: Any) -> None:
            client_id = getattr(event, "client_id", None)
            if client_id is None:  # a server-side assignment (sync), not a user change
                return
            value = getattr(getattr(event, "target", None), "value", None)
            try:
                self._worker.submit(self.handle_change, panel, kind, client_id, value)
            except RuntimeError:  # shut down
                log.debug("viser: %s from client %s after close", kind, client_id)

        return callback

    def handle_change(self, panel: ClientPanel, kind: str, client_id: int, value: object) -> None:
        """Act on one widget event of ``client_id``, or refuse it; never raises."""
        try:
            if client_id != panel.client_id:
                raise PermissionError(f"event of client {client_id} on another's panel")
            if kind == "unlock":
                self._unlock(panel)
            elif not self.policy.may_control(client_id):
                raise PermissionError("client is not an authenticated operator")
            elif kind in BUTTONS:
                self._press(kind)
            else:
                self._change(kind, value)
        except Exception as exc:
            self._count_rejection()
            level = logging.WARNING
            if not isinstance(exc, (PermissionError, ValueError)):  # ValidationError too
                level = logging.ERROR
            log.log(level, "viser: %s from client %s refused: %s", kind, client_id, exc)
            self._resync(panel)

    def _count_rejection(self) -> None:
        with self._rejected_lock:
            self.rejected += 1

    def close(self) -> None:
        self._worker.shutdown(wait=False, cancel_futures=True)

    def _unlock(self, panel: ClientPanel) -> None:
        if panel.token is None:
            return
        given = panel.token.value
        panel.token.value = ""
        if not self.policy.check_token(given):
            if panel.note is not None:
                panel.note.content = LOCKED_NOTE + "  \n**wrong token**"
            raise PermissionError("wrong operator token")
        self.policy.grant(panel.client_id)
        panel.set_locked(False)
        log.info("viser: client %s unlocked the operator controls", panel.client_id)

    def _press(self, kind: str) -> None:
        loop = self.actions.loop
        if kind == "start":
            loop.start_sim()
        elif kind == "stop":
            loop.stop_sim()
        else:
            loop.reset()
            viz = getattr(self.actions, "viz", None)
            if viz is not None:
                viz.on_reset()
            self.clear()

    def candidate(self, kind: str, value: object) -> SimConfig:
        """The configuration a change of one widget asks for (ValueError/ValidationError)."""
        if not value_ok(kind, value):
            raise ValueError(f"{value!r} is not a value of the {kind} widget")
        data = self.actions.loop.config.model_dump()
        if kind.startswith("led"):
            led = int(kind[3:])
            leds = set(data["led_dropout"]) - {led}
            data["led_dropout"] = sorted(leds | ({led} if value else set()))
        else:
            data[kind] = value
        return SimConfig.model_validate(data)

    def _change(self, kind: str, value: object) -> None:
        cfg = self.candidate(kind, value)
        if cfg != self.actions.loop.config:
            self.actions.apply_sim_config(cfg)  # syncs every panel (on_config)
            self.clear()

    def filter_update(self, client_id: int, message: Any) -> bool:
        """Message gate for client-scoped GUI updates, before viser touches the widget.

        Only ``value`` may change (not ``disabled``, ``max``...), and only to a value of the
        widget's type: a string for a slider, NaN or ∞ would raise inside viser. Range and
        access are checked by the callback (:meth:`handle_change`) once viser has taken the
        value into that client's own widget, so that a refusal re-syncs the sender's widget
        (viser's slider keeps its number box editable when the slider is disabled).
        """
        panel = self._panels.get(client_id)
        kind = panel.kinds.get(getattr(message, "uuid", None) or "") if panel else None
        if panel is None or kind is None:  # not one of ours (viser ignores unknown uuids)
            return self.policy.may_control(client_id)
        updates = getattr(message, "updates", None)
        ok = (
            isinstance(updates, dict)
            and set(updates) == {"value"}
            and well_typed(kind, updates["value"])
        )
        if not ok:
            self._count_rejection()
            log.warning("viser: dropped a %s update from client %s", kind, client_id)
        return ok

    def _resync(self, panel: ClientPanel) -> None:
        try:
            self._on_loop(functools.partial(self._sync_live, panel, None))
        except Exception:
            log.exception("viser: re-syncing the controls of client %s failed", panel.client_id)

    def _sync_live(self, panel: ClientPanel, fallback: Any) -> None:
        """Sync to the configuration in force when this runs (a queued sync is never stale)."""
        loop = getattr(self.actions, "loop", None)
        cfg = getattr(loop, "config", None)
        self._sync_panel(panel, cfg if cfg is not None else fallback)

    def _sync_panel(self, panel: ClientPanel, cfg: Any) -> None:
        panel.turbulence.value = cfg.turbulence
        panel.closure.value = float(cfg.closure_speed_mps)
        panel.noise.value = float(cfg.noise_sigma)
        panel.clutter.value = int(cfg.clutter)
        for i, h in enumerate(panel.dropout):
            h.value = (i + 1) in cfg.led_dropout

    def sync_config(self, cfg: Any) -> None:
        """Reflect a config changed elsewhere (REST, another client) in every client's widgets."""
        with self._panels_lock:
            panels = list(self._panels.values())
        for panel in panels:
            try:
                self._on_loop(functools.partial(self._sync_live, panel, cfg))
            except Exception:
                log.exception("viser: syncing the controls of client %s failed", panel.client_id)

    # ---- data ------------------------------------------------------------------------
    def clear(self) -> None:
        self._buf.clear()

    def _push(self, key: str, value: float) -> None:
        dq = self._buf.get(key)
        if dq is None:
            dq = self._buf[key] = deque(maxlen=WINDOW)
        dq.append(value)

    def record(self, record: TickRecord) -> None:
        """Accumulate one simulated tick into the chart buffers (cheap; every tick).

        The charts hold the current run only: a new run (or time going back) clears them, so
        that two runs are never joined by a line and the time axis (s since the run's start)
        stays monotonic, as uPlot requires.
        """
        if record.source != "sim":
            return
        ts = self._buf.get("t")
        if record.run != self._chart_run or (ts and record.t_s < ts[-1]):
            self._buf.clear()
            self._chart_run = record.run
        if record.miss_m is not None:  # set on the one tick that crosses the drogue plane
            self._last_miss = (float(record.miss_m), bool(record.captured), int(record.run))
        nan = float("nan")
        tip = np.asarray(record.probe_tip_m) if record.probe_tip_m is not None else None
        est = record.drogue_estimate_m or record.drogue_measured_m
        meas = np.asarray(est) - tip if est is not None and tip is not None else np.full(3, nan)
        ref = (
            np.asarray(record.reference_m) - tip
            if record.reference_m is not None and tip is not None
            else np.full(3, nan)
        )
        self._push("t", record.t_s)
        for i, a in enumerate("xyz"):
            self._push(f"m{a}", float(meas[i]))
            self._push(f"r{a}", float(ref[i]))
        rel = record.rel_position_m
        lat = float(np.hypot(rel[1], rel[2])) if rel is not None else nan
        self._push("miss", lat)
        c = record.control
        for name in ("throttle", "aileron", "elevator", "rudder"):
            self._push(name, getattr(c, name) if c is not None else nan)

    def _arr(self, key: str) -> np.ndarray:
        return np.asarray(self._buf.get(key, ()), dtype=np.float64)

    def refresh_plots(self, capture_radius_m: float) -> None:
        t = self._arr("t")
        if len(t) < 2:
            return
        self.plot_rel.data = (t, *(self._arr(k) for k in ("mx", "my", "mz", "rx", "ry", "rz")))
        self.plot_miss.data = (t, self._arr("miss"), np.full(len(t), capture_radius_m))
        self.plot_ctrl.data = (
            t,
            *(self._arr(k) for k in ("throttle", "aileron", "elevator", "rudder")),
        )

    def set_stopped(self) -> None:
        """The simulation is stopped: say so above the last status (no record says it)."""
        content = self.status.content
        if not content.startswith(STOPPED_NOTE):
            self.status.content = STOPPED_NOTE + "  \n" + content

    def set_status(self, record: TickRecord, tick_rate_hz: float, dropped: int) -> None:
        lock = "**LOCK**" if record.lock else f"**NO LOCK** ({record.lock_reason or '?'})"
        lat = record.timings_ms.get("step", record.timings_ms.get("total", float("nan")))
        lines = [
            lock,
            f"source **{record.source}** · run {record.run} · t = {record.t_s:.2f} s · "
            f"phase {record.phase or '–'}",
            f"tick rate {tick_rate_hz:.1f} Hz · dropped {dropped} · step {lat:.1f} ms",
        ]
        if record.rel_position_m is not None:
            r = record.rel_position_m
            lines.append(f"drogue − probe: ({r[0]:+.2f}, {r[1]:+.2f}, {r[2]:+.2f}) m")
        stream, guidance = getattr(record, "stream", None), getattr(record, "guidance", None)
        if stream is not None:  # a camera stream (app.streams): rate, drops, skew, tracker
            skew = "–" if stream.skew_ms is None else f"{stream.skew_ms:.1f}"
            lines.append(
                f"{stream.fps:.1f} fps · dropped {stream.dropped_skew} (skew) "
                f"{stream.dropped_backpressure} (newest kept) · skew {skew} ms · {stream.mode}"
            )
        if guidance is not None and guidance.closure_speed_mps is not None:
            ttc = guidance.time_to_contact_s
            lines.append(
                f"closure {guidance.closure_speed_mps:+.2f} m/s · "
                f"contact in {'–' if ttc is None else f'{ttc:.1f} s'} · "
                f"predicted miss {guidance.predicted_miss_m or 0.0:.3f} m"
            )
        if record.captured is not None:
            lines.append("**captured**" if record.captured else "not captured")
        if self._last_miss is not None:
            miss, captured, run = self._last_miss
            lines.append(
                f"last plane crossing: miss {miss:.3f} m (run {run}"
                + (", captured)" if captured else ")")
            )
        self.status.content = "  \n".join(lines)

    def set_images(self, record: TickRecord, raw: RawFrame | None) -> None:
        sides: tuple[tuple[Side, Any], ...] = (("left", self.img_left), ("right", self.img_right))
        for side, handle in sides:
            img = None if raw is None else (raw.left_image if side == "left" else raw.right_image)
            if img is not None:
                windows = None if raw is None else raw.image_windows_px
                handle.image = annotate(
                    img,
                    record.pose,
                    side,
                    lock=record.lock,
                    windows_px=None if windows is None else windows[side == "right"],
                )
