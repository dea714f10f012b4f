"""
Array type aliases shared by every layer (one place, so a dtype means the same everywhere).

Coordinates are float64 unless a name says otherwise: the decoder keeps float32 clouds as they
are (:data:`Float32Array`) and the filters return float64.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: float64 arrays: points (N, 3), rotations (3, 3), extents, directions.
FloatArray = NDArray[np.float64]
#: float32 arrays: clouds as sensors and PointCloud2 messages deliver them.
Float32Array = NDArray[np.float32]
#: Indices into other arrays (point indices of a box, hull vertices).
IndexArray = NDArray[np.intp]
#: Masks.
BoolArray = NDArray[np.bool_]
#: int32 images (labels of rendered depth frames).
IntArray = NDArray[np.int32]
