"""The navigation pipeline's memory of its last lock (the *track*).

:class:`~app.vision.pipeline.NavigationPipeline` keeps one :class:`TrackMemory` after each
lock: it continues the LED ids through roll (:mod:`app.geometry.led_ids`) and, as a
:class:`~app.geometry.ring.RingPrior`, lets a 3-LED ring fit that agrees with it be judged in
its neighbourhood. :class:`~app.vision.tracking.StereoTracker` reads it after an acquisition
and continues it through tracked frames (:meth:`NavigationPipeline.continue_track`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class TrackMemory:
    """The last lock: prior for the next frame's ids (roll continuity) and 3-LED integrity.

    ``center_mm``: the ring's centre (mm, left camera frame); ``normal``: its unit normal
    towards the cameras; ``roll_deg``: the roll of the LED ids (deg); ``age``: frames since
    the lock (the pipeline forgets the track after ``PipelineConfig.track_frames``)."""

    center_mm: np.ndarray
    normal: np.ndarray
    roll_deg: float
    age: int = 0
