"""The checkerboard of a calibration set (paper §3.2: the CCP of Zhang's method): its size in
inner corners and squares (mm), the board-spec parser, pair names, and the error every step of
:mod:`app.calibration` raises for a set that cannot be calibrated."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray


class CheckerboardError(ValueError):
    """A checkerboard set cannot be calibrated; the message says why, in one line."""


@dataclass(frozen=True)
class Board:
    """``cols`` × ``rows`` inner corners (OpenCV's patternSize), squares of ``square_mm``."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: need at least 3x3 inner corners "
                "(the board size counts inner corners, i.e. squares - 1)"
            )
        if self.cols == self.rows:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: a square board's orientation is ambiguous; "
                "use a board with different inner-corner counts per row and column"
            )
        if not (math.isfinite(self.square_mm) and self.square_mm > 0):
            raise CheckerboardError(
                f"square size must be a positive number of mm, got {self.square_mm}"
            )

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> NDArray[np.float32]:
        """Inner corners in the board frame (N×3, mm), row-major: corner (i, j) at (i·s, j·s, 0)."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * self.square_mm
        return pts.astype(np.float32)


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` → (9, 6) inner corners per row × per column."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×*,]\s*(\d+)\s*", str(text))
    if not m:
        raise CheckerboardError(f"board {text!r}: expected COLSxROWS inner corners, e.g. 9x6")
    return int(m.group(1)), int(m.group(2))


def pair_name(left_file: str, right_file: str) -> str:
    """Short name of a stereo pair from its file names: ``left_03.png``/``right_03.png`` → ``03``."""
    ls, rs = Path(left_file).stem, Path(right_file).stem
    for lp, rp in (("left", "right"), ("l", "r")):
        if ls.lower().startswith(lp) and rs.lower().startswith(rp):
            rest_l, rest_r = ls[len(lp) :], rs[len(rp) :]
            if rest_l == rest_r and rest_l.strip("_-. "):
                return rest_l.strip("_-. ")
    return ls if ls == rs else f"{ls}|{rs}"
