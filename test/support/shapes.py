"""Test shapes without ROS (the graph tests and the compiled kernels' tests share them)."""

from __future__ import annotations

import numpy as np


def l_shape_points(seed: int = 0, count: int = 4000) -> np.ndarray:
    """
    Return points on the surface of an L-shaped object of two boxes (metres, ~0.1-0.2 m).

    The fit-and-split decomposition splits it into two boxes at the default threshold.
    """
    rng = np.random.default_rng(seed)
    parts = []
    for low, high in (((0.0, 0.0, 0.0), (0.20, 0.05, 0.05)), ((0.0, 0.0, 0.0), (0.05, 0.05, 0.2))):
        low_corner, high_corner = np.array(low), np.array(high)
        samples = rng.uniform(low_corner, high_corner, size=(count // 2, 3))
        axis = rng.integers(0, 3, size=len(samples))
        side = rng.integers(0, 2, size=len(samples))
        samples[np.arange(len(samples)), axis] = np.where(
            side == 1, high_corner[axis], low_corner[axis]
        )
        parts.append(samples)
    return np.concatenate(parts) + np.array([0.1, -0.05, 0.6])
