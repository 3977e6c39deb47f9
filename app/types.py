"""Array types shared by the package (numpy's typing; shapes and units are in each name's
docstring or the function's)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: float64 arrays: points, vectors, matrices (units in the names that use them: mm, m, px, rad)
FloatArray = npt.NDArray[np.float64]
#: int64 arrays: indices, labels, counts
IntArray = npt.NDArray[np.int64]
#: uint8 arrays: 8-bit images (H×W gray or H×W×3 BGR) and masks
UInt8Array = npt.NDArray[np.uint8]
#: boolean arrays: masks, flags per element
BoolArray = npt.NDArray[np.bool_]
#: a JSON object as the service sends or reads it (its values: JSON values, nested)
JsonObject = dict[str, object]
#: an image rectangle (x0, y0, x1, y1) in pixels, half-open
Rect = tuple[int, int, int, int]
