"""Hostile navigation scenarios and their scoring (no wrong lock, lock rate).

Shared by ``tests/vision/test_integrity_hostile.py`` (which asserts zero wrong locks) and
``benchmarks/hostile_cases.py`` (which prints the README's table with more seeds).

A **wrong lock** is a lock whose drogue centre is more than 5 mm from the truth, or one that
reports an LED more than 5 mm from every real LED (occluded LEDs included).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from app.sim.led_ring import LedRing, random_pose
from app.sim.stereo_render import RenderedPair, RenderSettings, render_pair
from app.vision.pipeline import NavigationPipeline, PipelineConfig

WRONG_MM = 5.0


@dataclass(frozen=True)
class HostileCase:
    """One scenario: render settings per seed, pose range/tilt, ring, pipeline config."""

    name: str
    settings: Callable[[int], RenderSettings]
    range_mm: float = 1500.0
    max_tilt_deg: float = 20.0
    min_tilt_deg: float = 0.0
    ring: LedRing = field(default_factory=LedRing)
    config: PipelineConfig = field(default_factory=PipelineConfig)
    leds_present: bool = True  # False: any lock is wrong
    min_lock_rate: float = 0.0  # asserted by the tests (docs/integrity.md)


@dataclass
class CaseStats:
    name: str
    frames: int = 0
    locks: int = 0
    wrong: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    ms: list[float] = field(default_factory=list)

    @property
    def lock_rate(self) -> float:
        return self.locks / max(self.frames, 1)


def is_wrong_lock(result: PoseResult, pair: RenderedPair, leds_present: bool = True) -> bool:
    """The integrity criterion of the module docstring."""
    if not result.lock:
        return False
    if not leds_present or result.drogue is None:
        return True
    t = pair.truth
    if np.linalg.norm(np.array(result.drogue.center_mm) - t.center_mm) > WRONG_MM:
        return True
    for led in result.leds:
        if np.min(np.linalg.norm(t.led_xyz_mm - np.array(led.xyz_mm), axis=1)) > WRONG_MM:
            return True
    return False


def _pose(rng: np.random.Generator, case: HostileCase, calib: StereoCalibration):
    for _ in range(100):
        c, n = random_pose(rng, case.range_mm, case.max_tilt_deg, calib=calib, ring=case.ring)
        tilt = float(np.degrees(np.arccos(np.clip(-n[2], -1, 1))))
        if tilt >= case.min_tilt_deg:
            return c, n
    return c, n


def run_case(calib: StereoCalibration, case: HostileCase, seeds: range) -> CaseStats:
    """Render and solve one frame per seed (a fresh pipeline each: no track)."""
    stats = CaseStats(case.name)
    for seed in seeds:
        rng = np.random.default_rng([seed, 7])
        centre, normal = _pose(rng, case, calib)
        roll = float(rng.uniform(-np.pi, np.pi))
        pair = render_pair(
            calib, centre, normal, case.settings(seed), ring=case.ring, seed=seed, roll_rad=roll
        )
        t0 = time.perf_counter()
        res = NavigationPipeline(calib, case.config).process(pair.left, pair.right)
        stats.ms.append((time.perf_counter() - t0) * 1e3)
        stats.frames += 1
        stats.locks += int(res.lock)
        stats.wrong += int(is_wrong_lock(res, pair, case.leds_present))
        if not res.lock and res.reason:
            key = res.reason.split(":")[0].split("(")[0].strip()[:60]
            stats.reasons[key] = stats.reasons.get(key, 0) + 1
    return stats


def _reflections(offset_deg: float, occluded: tuple[int, ...]) -> Callable[[int], RenderSettings]:
    """A rim reflection ``offset_deg`` from LED 2 (either side, by seed), LEDs occluded."""

    def make(seed: int) -> RenderSettings:
        sign = 1.0 if seed % 2 else -1.0
        return RenderSettings(rim_reflections=((2, sign * offset_deg),), occluded=occluded)

    return make


def _fixed(settings: RenderSettings) -> Callable[[int], RenderSettings]:
    """The same settings for every seed."""
    return lambda _seed: settings


def hostile_cases() -> list[HostileCase]:
    """The hostile set (see the module docstring of each renderer extra)."""
    cases: list[HostileCase] = []
    for g in (0, 10, 30, 50, 80):
        cases.append(
            HostileCase(
                f"{g} LED-like 3-D glints",
                _fixed(RenderSettings(glints=g)),
                min_lock_rate=0.9 if g <= 30 else 0.0,
            )
        )
    for g in (30, 80):
        cases.append(
            HostileCase(
                f"{g} glints, no LEDs",
                _fixed(RenderSettings(glints=g, occluded=(1, 2, 3, 4, 5))),
                leds_present=False,
            )
        )
    cases.append(
        HostileCase(
            "30 glints, 2 LEDs occluded", lambda s: RenderSettings(glints=30, occluded=(2, 4))
        )
    )
    cases.append(
        HostileCase(
            "30 whitish glints, colour frames",
            lambda s: RenderSettings(glints=30, color=True),
            min_lock_rate=0.9,
        )
    )
    cases.append(
        HostileCase(
            "30 LED-green glints, colour frames",
            lambda s: RenderSettings(glints=30, color=True, glint_led_color=True),
        )
    )
    cases.append(HostileCase("40 monocular glints", lambda s: RenderSettings(mono_glints=40)))
    for off in (5.0, 8.0, 12.0, 20.0, 36.0):
        for occ in ((), (1,), (1, 3)):
            label = "none" if not occ else "+".join(map(str, occ))
            cases.append(
                HostileCase(
                    f"rim reflection {off:.0f}° from LED 2, occluded: {label}",
                    _reflections(off, occ),
                )
            )
    cases.append(
        HostileCase(
            "rim reflection 10° + 30 glints + LED 1 occluded",
            lambda s: RenderSettings(glints=30, rim_reflections=((2, 10.0),), occluded=(1,)),
        )
    )
    for lo, hi in ((40.0, 60.0), (60.0, 75.0), (75.0, 80.0)):
        cases.append(
            HostileCase(
                f"edge-on, tilt {lo:.0f}–{hi:.0f}°",
                lambda s: RenderSettings(),
                max_tilt_deg=hi,
                min_tilt_deg=lo,
            )
        )
    for count in (4, 6, 8, 10):
        cases.append(
            HostileCase(
                f"{count}-LED ring, led_count=5",
                lambda s: RenderSettings(),
                ring=LedRing(count=count),
                leds_present=False,
            )
        )
    return cases
