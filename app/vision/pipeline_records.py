"""Frozen records handed between the phases of :meth:`NavigationPipeline._solve`
(:mod:`app.vision.pipeline`): match (eq. 14) → triangulate (eqs. 15–16) → ring (§5.2) → ids."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.vision.matching import MatchArrays
from app.vision.types import Blob, FeatureSet


@dataclass(frozen=True)
class StereoMatches:
    """The matches of one frame pair (eq. 14) with every candidate's undistorted pixel.

    ``left_px``/``right_px``: (NL, 2)/(NR, 2) undistorted centroids of all candidate blobs
    (px, the pinhole image of each camera); ``arrays``: the matched index pairs and their
    descriptor and epipolar distances."""

    left_px: np.ndarray
    right_px: np.ndarray
    arrays: MatchArrays


@dataclass(frozen=True)
class StereoPoints:
    """The triangulated matches of one frame pair (eqs. 15–16 + reprojection refinement).

    Row ``j`` of ``xyz_mm`` (M, 3; mm, left camera frame) and ``reprojection_px`` (M,; px)
    is match ``j`` of ``matches``: left blob ``matches.left[j]`` of ``left``, right blob
    ``matches.right[j]`` of ``right``."""

    left: FeatureSet
    right: FeatureSet
    matches: MatchArrays
    xyz_mm: np.ndarray
    reprojection_px: np.ndarray

    def left_blobs(self, rows: list[int]) -> list[Blob]:
        """The left blobs of matches ``rows``."""
        return [self.left.blobs[int(self.matches.left[j])] for j in rows]

    def right_blobs(self, rows: list[int]) -> list[Blob]:
        """The right blobs of matches ``rows``."""
        return [self.right.blobs[int(self.matches.right[j])] for j in rows]


@dataclass(frozen=True)
class RingIds:
    """The LED ids of a ring fit: ``roll_deg`` the roll the ids follow (deg,
    :mod:`app.geometry.led_ids`), ``ids`` (K,) the id of each of the fit's slots."""

    roll_deg: float
    ids: np.ndarray


@dataclass(frozen=True)
class RingLeds:
    """The ring's LEDs in id order: ``ids`` and ``rows`` (their matches), the blobs of both
    images, their centroid σ (left, right; px) and their points (K, 3; mm)."""

    ids: list[int]
    rows: list[int]
    left: list[Blob]
    right: list[Blob]
    sigmas_px: list[tuple[float, float]]
    xyz_mm: np.ndarray
