"""The array types geometry is written in: float64 for coordinates and transforms, float32 for
what the engines and RANSAC exchange."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["F32", "F64"]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
