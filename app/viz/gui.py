"""viser GUI panel: simulation controls, live uPlot charts, status, camera images."""

from __future__ import annotations

import logging
from collections import deque
from typing import Any

import numpy as np
import viser
import viser.uplot as uplot

from app.viz.overlay import draw_detections

log = logging.getLogger(__name__)
WINDOW = 300  # samples kept in each chart (fixed window)
TURBULENCE = ("none", "light", "moderate", "severe")
XYZ_COLORS = ("#e04040", "#30a050", "#3070e0")
CTRL_COLORS = ("#444444", "#e08020", "#2090d0", "#a040c0")


def _series(label: str, color: str, dash: bool = False) -> uplot.Series:
    s: dict[str, Any] = {"label": label, "stroke": color, "width": 1.5}
    if dash:
        s["dash"] = (6.0, 4.0)
    return s  # type: ignore[return-value]


class DockingGui:
    """Builds the panel once; :meth:`update` feeds charts/status; callbacks drive ``actions``.

    ``actions`` is the service state (:class:`app.server.dependencies.AppState`): its ``loop``
    (start/stop/reset) and ``apply_sim_config``.
    """

    def __init__(self, server: viser.ViserServer, actions: Any) -> None:
        self.server = server
        self.actions = actions
        gui = server.gui
        gui.configure_theme(control_width="medium")
        self.status = gui.add_markdown("**starting…**")
        self._buf: dict[str, deque[float]] = {}
        self._syncing = False

        with gui.add_folder("Simulation"):
            self.btn_start = gui.add_button("Start", icon=viser.Icon.PLAYER_PLAY)
            self.btn_stop = gui.add_button("Stop", icon=viser.Icon.PLAYER_STOP)
            self.btn_reset = gui.add_button("Reset", icon=viser.Icon.REFRESH)
            cfg = actions.loop.config
            self.turbulence = gui.add_dropdown(
                "Turbulence", TURBULENCE, initial_value=cfg.turbulence
            )
            self.closure = gui.add_slider(
                "Closure (m/s)", min=0.2, max=3.0, step=0.1, initial_value=cfg.closure_speed_mps
            )
            self.noise = gui.add_slider(
                "Noise σ (DN)", min=0.0, max=20.0, step=0.5, initial_value=cfg.noise_sigma
            )
            self.clutter = gui.add_slider(
                "Clutter lights", min=0, max=20, step=1, initial_value=cfg.clutter
            )
            self.dropout = [
                gui.add_checkbox(f"LED {i} off", initial_value=i in cfg.led_dropout)
                for i in range(1, 6)
            ]

        self.btn_start.on_click(lambda _: actions.loop.start_sim())
        self.btn_stop.on_click(lambda _: actions.loop.stop_sim())
        self.btn_reset.on_click(lambda _: self._reset())
        for h in (self.turbulence, self.closure, self.noise, self.clutter, *self.dropout):
            h.on_update(self._on_control)

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
                aspect=2.0,
            )
        with gui.add_folder("Cameras"):
            blank = np.zeros((256, 320, 3), np.uint8)
            self.img_left = gui.add_image(blank, label="left", format="jpeg")
            self.img_right = gui.add_image(blank, label="right", format="jpeg")

    # ---- callbacks -------------------------------------------------------------------
    def _reset(self) -> None:
        self.actions.loop.reset()
        self.clear()

    def _on_control(self, event: Any) -> None:
        if self._syncing or event.client is None:  # server-side sync, not a user change
            return
        from app.server.schemas import SimConfig

        update = {
            "turbulence": self.turbulence.value,
            "closure_speed_mps": float(self.closure.value),
            "noise_sigma": float(self.noise.value),
            "clutter": int(self.clutter.value),
            "led_dropout": [i + 1 for i, h in enumerate(self.dropout) if h.value],
        }
        try:
            cfg = SimConfig.model_validate({**self.actions.loop.config.model_dump(), **update})
        except Exception as exc:  # pragma: no cover - the widgets' ranges are valid
            log.warning("GUI config rejected: %s", exc)
            return
        self.actions.apply_sim_config(cfg)
        self.clear()

    def sync_config(self, cfg: Any) -> None:
        """Reflect a config changed elsewhere (REST) in the widgets."""
        self._syncing = True
        try:
            self.turbulence.value = cfg.turbulence
            self.closure.value = cfg.closure_speed_mps
            self.noise.value = cfg.noise_sigma
            self.clutter.value = cfg.clutter
            for i, h in enumerate(self.dropout):
                h.value = (i + 1) in cfg.led_dropout
        finally:
            self._syncing = False

    # ---- data ------------------------------------------------------------------------
    def clear(self) -> None:
        self._buf.clear()

    def _push(self, key: str, value: float) -> None:
        dq = self._buf.get(key)
        if dq is None:
            dq = self._buf[key] = deque(maxlen=WINDOW)
        dq.append(value)

    def record(self, record: Any) -> None:
        """Accumulate one simulated tick into the chart buffers (cheap; every tick)."""
        if record.source != "sim":
            return
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

    def set_status(self, record: Any, tick_rate_hz: float, dropped: int) -> None:
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
        if record.captured is not None:
            cap = "**captured**" if record.captured else "not captured"
            miss = f" · miss {record.miss_m:.3f} m" if record.miss_m is not None else ""
            lines.append(cap + miss)
        self.status.content = "  \n".join(lines)

    def set_images(self, record: Any, raw: Any) -> None:
        for side, handle in (("left", self.img_left), ("right", self.img_right)):
            img = getattr(raw, f"{side}_image", None)
            if img is not None:
                handle.image = draw_detections(img, record.pose, side, width=320, lock=record.lock)
