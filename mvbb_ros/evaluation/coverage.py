"""
How well boxes describe a whole object: surface coverage, volume ratio and thin plates.

The single-view benchmark (``benchmarks/views.py``, issue 15) compares the boxes decomposed from
one partial view with the object's complete mesh. The measures, all from the boxes and the mesh:

* **coverage**: the share of points sampled uniformly by area on the whole mesh surface (every
  side, seen or not; :data:`SURFACE_SAMPLES` with a fixed seed) that lie inside the union of
  the boxes, each box grown by :data:`COVERAGE_TOLERANCE` (2 mm, about the depth noise of a
  Kinect-class sensor at 0.5-1 m, so a box fitted to noisy points of a face still covers it);
* **volume ratio**: the boxes' total volume (overlaps counted twice) over the volume of the
  mesh's convex hull;
* **thin boxes**: boxes whose smallest extent is under :data:`THIN_BOX` (1 cm): plates of
  sensor thickness rather than parts of the object.

Lengths are in the mesh's units (metres for the benchmark).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from mvbb_ros.arrays import BoolArray, cross, FloatArray
from mvbb_ros.geometry.box import Box
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

#: Points sampled on the whole surface for coverage (area-uniform, fixed seed).
SURFACE_SAMPLES = 20_000
#: Seed of the surface sample.
SURFACE_SEED = 0
#: Growth of every box for coverage, metres: about the sensor's depth noise (sigma 0.8-1.7 mm
#: and a disparity step of 0.7-2.9 mm at 0.5-1 m for the Kinect-like model).
COVERAGE_TOLERANCE = 0.002
#: A box whose smallest extent is below this (metres) is a thin plate.
THIN_BOX = 0.01


def sample_surface(
    vertices: ArrayLike,
    triangles: ArrayLike,
    count: int = SURFACE_SAMPLES,
    seed: int = SURFACE_SEED,
) -> FloatArray:
    """
    Return points drawn uniformly by area on a triangle mesh (every side of it).

    A triangle is chosen with probability proportional to its area, then a uniform point in it
    (reflected barycentric coordinates).

    :param vertices: (V, 3) vertex coordinates.
    :param triangles: (T, 3) vertex indices.
    :param count: how many points.
    :param seed: the random seed; the same mesh and seed give the same points.
    :return: (count, 3) points.
    :raises ValueError: when the mesh has no area.
    """
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.intp)]
    areas = np.linalg.norm(
        cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    if not areas.sum() > 0.0:
        raise ValueError('sample_surface: the mesh has no area')
    rng = np.random.default_rng(seed)
    chosen = corners[rng.choice(len(corners), size=count, p=areas / areas.sum())]
    u, v = rng.random((2, count, 1))
    flip = u + v > 1.0
    u, v = np.where(flip, 1.0 - u, u), np.where(flip, 1.0 - v, v)
    return chosen[:, 0] + u * (chosen[:, 1] - chosen[:, 0]) + v * (chosen[:, 2] - chosen[:, 0])


def covered(
    boxes: Sequence[Box], points: ArrayLike, tolerance: float = COVERAGE_TOLERANCE
) -> BoolArray:
    """
    Tell, per point, whether it lies in the union of the boxes, each grown by `tolerance`.

    :param boxes: the boxes.
    :param points: (N, 3) points in the boxes' frame.
    :param tolerance: growth of each box on every side (same units).
    :return: (N,) booleans.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inside = np.zeros(len(pts), dtype=bool)
    for box in boxes:
        inside |= box.contains(pts, tol=tolerance)
    return inside


def convex_hull_volume(points: ArrayLike) -> float:
    """Return the volume of the convex hull of (N, 3) points (0 when they span no volume)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 4:
        return 0.0
    try:
        return float(ConvexHull(pts).volume)
    except (QhullError, ValueError):  # flat or degenerate sets have no volume
        return 0.0


@dataclass(frozen=True)
class BoxMetrics:
    """
    The boxes of one cloud against the whole object.

    :ivar boxes: how many boxes.
    :ivar thin: how many of them have a smallest extent under the thin limit.
    :ivar coverage: share in [0, 1] of the whole surface inside the union of the boxes.
    :ivar volume_ratio: total box volume over the mesh's convex-hull volume.
    """

    boxes: int
    thin: int
    coverage: float
    volume_ratio: float

    @property
    def thin_share(self) -> float:
        """Share of thin boxes (0 without boxes)."""
        return self.thin / self.boxes if self.boxes else 0.0


def box_metrics(
    boxes: Sequence[Box],
    surface: ArrayLike,
    hull_volume: float,
    *,
    tolerance: float = COVERAGE_TOLERANCE,
    thin: float = THIN_BOX,
) -> BoxMetrics:
    """
    Measure boxes against a whole object given by its surface sample and hull volume.

    :param boxes: the boxes, in the frame of `surface`.
    :param surface: (N, 3) points sampled on the whole surface (:func:`sample_surface`).
    :param hull_volume: the volume of the object's convex hull (> 0).
    :param tolerance: growth of each box for coverage.
    :param thin: smallest extent under which a box is a thin plate.
    :return: the metrics.
    :raises ValueError: for an empty surface sample or a hull without volume.
    """
    pts = np.asarray(surface, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0 or not hull_volume > 0.0:
        raise ValueError('box_metrics needs surface points and a hull volume > 0')
    return BoxMetrics(
        boxes=len(boxes),
        thin=thin_count(boxes, thin),
        coverage=float(np.mean(covered(boxes, pts, tolerance))),
        volume_ratio=float(sum(box.volume for box in boxes)) / hull_volume,
    )


def thin_count(boxes: Sequence[Box], thin: float = THIN_BOX) -> int:
    """Return how many boxes have a smallest extent under `thin`."""
    return sum(float(np.min(box.extents)) < thin for box in boxes)
