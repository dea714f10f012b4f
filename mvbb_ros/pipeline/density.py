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

from mvbb_ros.arrays import BoolArray, column_max, column_min, FloatArray
from mvbb_ros.geometry.views.cells import search_tree
from mvbb_ros.pipeline.filtering import crop_points, filter_points
import numba as nb
import numpy as np
from numpy.typing import NDArray

#: A finer edge is used only when it is at most this share of the voxel size (a few per cent
#: finer would add work for nothing).
MEANINGFUL_SHARE = 0.9
#: The most cells of the grid that spares most raw points their nearest-point query
#: (:func:`_near_in_own_cell`); a larger object's points are all queried.
MAX_NEAR_CELLS = 4_000_000
#: A raw point that shares its cell with an object's point this much inside the reach
#: (relative) is near it without a query: far above the rounding of either distance.
NEAR_SLACK = 1e-9


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
    region = np.asarray(crop_points(raw, low, high), dtype=np.float64)
    if not len(region):
        return None
    # Most raw points share a voxel-sized cell with one of the object's points, so lie within a
    # voxel's diagonal of it: near without a query. The others are queried (the same points
    # as querying every one: a point near without a query is near by the query too).
    keep = _near_in_own_cell(
        region,
        np.ascontiguousarray(observed, dtype=np.float64),
        voxel_size,
        (reach * reach) * (1.0 - NEAR_SLACK),
        MAX_NEAR_CELLS,
    )
    rest = np.flatnonzero(~keep)
    if len(rest):
        distances, _ = search_tree(observed).query(region[rest], distance_upper_bound=reach)
        keep[rest] = np.isfinite(distances)
    near = np.compress(keep, region, axis=0)
    points, _ = filter_points(
        near,
        voxel_size=edge,
        outlier_neighbors=outlier_neighbors,
        outlier_std_ratio=outlier_std_ratio,
    )
    if len(points) <= len(observed):
        return None
    return FinerPoints(points, edge)


@nb.njit(
    'boolean[::1](float64[:, ::1], float64[:, ::1], float64, float64, int64)',
    cache=True,
    nogil=True,
)
def _near_in_own_cell(
    points: FloatArray, anchors: FloatArray, cell: float, limit: float, max_cells: int
) -> BoolArray:
    """
    Tell which `points` lie within sqrt(`limit`) of an anchor in their own grid cell.

    The cells are `cell` wide from the anchors' lowest corner; each cell keeps its first
    anchor. False where no anchor shares the cell or it is farther (a point may still be near
    another anchor), and for every point when the grid would have more than `max_cells` cells.
    """
    count = points.shape[0]
    near = np.zeros(count, dtype=np.bool_)
    low = np.empty(3)
    spans = np.empty(3, dtype=np.int64)
    cells = 1
    for axis in range(3):
        low[axis] = anchors[0, axis]
        high = anchors[0, axis]
        for j in range(anchors.shape[0]):
            low[axis] = min(low[axis], anchors[j, axis])
            high = max(high, anchors[j, axis])
        extent = (high - low[axis]) / cell
        if not extent < max_cells:
            return near
        spans[axis] = int(extent) + 1
        cells *= spans[axis]  # at most max_cells squared: no overflow
        if cells > max_cells:
            return near
    first = np.full(cells, -1, dtype=np.int64)
    for j in range(anchors.shape[0]):
        key = 0
        for axis in range(3):
            place = min(int((anchors[j, axis] - low[axis]) / cell), spans[axis] - 1)
            key = key * spans[axis] + place
        if first[key] < 0:
            first[key] = j
    for i in range(count):
        key = 0
        inside = True
        for axis in range(3):
            place = (points[i, axis] - low[axis]) / cell
            if not (place >= 0.0 and place < spans[axis]):
                inside = False
                break
            key = key * spans[axis] + int(place)
        if not inside:
            continue
        j = first[key]
        if j < 0:
            continue
        dx = points[i, 0] - anchors[j, 0]
        dy = points[i, 1] - anchors[j, 1]
        dz = points[i, 2] - anchors[j, 2]
        near[i] = dx * dx + dy * dy + dz * dz <= limit
    return near


def warm_up() -> None:
    """Run the module's kernel once (see :mod:`mvbb_ros.kernels`)."""
    points = np.zeros((2, 3))
    _near_in_own_cell(points, points, 1.0, 1.0, 8)
