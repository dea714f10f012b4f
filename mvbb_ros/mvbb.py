"""Minimum-volume bounding box (interim: best of PCA and axis-aligned; replaced by issue 3)."""

from __future__ import annotations

from mvbb_ros.box import Box
import numpy as np
from numpy.typing import ArrayLike


def minimum_bounding_box(points: ArrayLike, *, seed: int = 0) -> Box:
    """Return a tight oriented box enclosing every point of `points` ((N, 3))."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError('minimum_bounding_box needs at least one point, got an empty array')
    if not np.all(np.isfinite(pts)):
        raise ValueError('minimum_bounding_box got non-finite coordinates (NaN or inf)')
    centered = pts - pts.mean(axis=0)
    _, vectors = np.linalg.eigh(centered.T @ centered)
    return min((Box.enclosing(pts), Box.enclosing(pts, vectors)), key=lambda box: box.volume)
