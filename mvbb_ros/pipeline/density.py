"""
A small object's points sampled again, finer: enough of them for its boxes and its grasps.

The voxel grid's edge (``voxel_size``) suits the objects a frame usually holds; a small object
keeps only a few dozen of its points at that edge, too few for the contacts of a gripper's pads
to be found on it. :func:`finer_object_points` takes the object's raw points again (those of the
cloud near its filtered points) through the same voxel grid and outlier removal at an edge that
grows with the object's size: its largest extent over ``object_voxel_cells``, not below
``min_voxel_size``, not above ``voxel_size``. Objects large enough keep their points as they are.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from mvbb_ros.arrays import column_max, column_min, FloatArray
from mvbb_ros.geometry.views.cells import search_tree
from mvbb_ros.pipeline.filtering import filter_points
import numpy as np
from numpy.typing import NDArray

#: A finer edge is used only when it is at most this share of the voxel size (a few per cent
#: finer would add work for nothing).
MEANINGFUL_SHARE = 0.9


@dataclass(frozen=True)
class FinerPoints:
    """An object's points sampled again: the points (M, 3) and the voxel edge (metres)."""

    points: FloatArray
    voxel_size: float


def largest_extent(points: FloatArray) -> float:
    """Return the points' largest extent along their principal axes (metres; any rotation)."""
    if len(points) < 2:
        return 0.0
    centred = points - points.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    along = centred @ axes.T
    return float(np.max(column_max(along) - column_min(along)))


def object_voxel_size(
    points: FloatArray, voxel_size: float, cells: int, min_voxel_size: float
) -> float:
    """
    Return the voxel edge for an object (metres): its largest extent over `cells`, clamped.

    Between `min_voxel_size` and `voxel_size`; `voxel_size` when `cells` is 0 (off).
    """
    if cells <= 0 or voxel_size <= 0.0:
        return voxel_size
    edge = largest_extent(points) / cells
    return min(voxel_size, max(min_voxel_size, edge))


def finer_object_points(
    observed: FloatArray,
    raw: NDArray[np.floating],
    voxel_size: float,
    cells: int,
    min_voxel_size: float,
    outlier_neighbors: int,
    outlier_std_ratio: float,
) -> FinerPoints | None:
    """
    Return an object's points sampled again at its own finer edge, or None when not finer.

    :param observed: the object's filtered points (voxel centroids at `voxel_size`).
    :param raw: the points the voxel grid was made of (the cloud, cropped), metres, float32 or
        float64.
    :param voxel_size: the frame's voxel edge (metres).
    :param cells: the object's largest extent is cut into this many voxels (0: off).
    :param min_voxel_size: the finest edge (metres; about the sensor's point spacing).
    :param outlier_neighbors: the frame's outlier removal, run on the finer points too.
    :param outlier_std_ratio: the same.
    :return: the raw points within a voxel's diagonal of `observed` (the object's voxels, and
        nothing of a neighbour, which lies further than the cluster tolerance), through the voxel
        grid at the finer edge and the outlier removal; None when the edge would not be
        meaningfully finer (:data:`MEANINGFUL_SHARE`) or fewer points would come out.
    """
    edge = object_voxel_size(observed, voxel_size, cells, min_voxel_size)
    if not len(observed) or edge > MEANINGFUL_SHARE * voxel_size:
        return None
    reach = voxel_size * math.sqrt(3.0)
    low = column_min(observed) - reach
    high = column_max(observed) + reach
    inside = np.all((raw >= low) & (raw <= high), axis=1)
    region = np.asarray(raw[inside], dtype=np.float64)
    if not len(region):
        return None
    distances, _ = search_tree(observed).query(region, distance_upper_bound=reach)
    near = region[np.isfinite(distances)]
    points, _ = filter_points(
        near,
        voxel_size=edge,
        outlier_neighbors=outlier_neighbors,
        outlier_std_ratio=outlier_std_ratio,
    )
    if len(points) <= len(observed):
        return None
    return FinerPoints(points, edge)
