"""
The result of a fit-and-split decomposition: the box tree, and the settings it was made with.

:class:`Decomposition` holds the input points and every node of the tree
(:class:`DecompositionNode`: its box and points, the cut tested, theta and Theta*, why it was
not split), gives the leaf boxes, their points and the dropped ones, and writes it all as JSON.
:class:`DecompositionSettings` validates the arguments of
:func:`~mvbb_ros.geometry.decomposition.tree.decompose`, which builds the tree. No ROS import.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import json
import math
from typing import Any, get_args, Literal

from mvbb_ros.arrays import IndexArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition import split as splitting
import numpy as np
from numpy.typing import NDArray

#: Default gain threshold t (the paper's middle setting).
DEFAULT_GAIN_THRESHOLD = 0.94
#: Default smallest point count of a kept box. Measured with ``benchmarks/decompose.py --sweep
#: min_points`` on the real scans with 0.5 % added outliers at t = 0.94: 10 drops over a quarter
#: of the outliers (1 drops none, and 4 keeps 3-point flat boxes), at most 0.07 % of a scan's
#: real points, and cuts the boxes per scan from 12 to 7; 20 drops more outliers but also more
#: real vertices of the paper's mug (45 against 33 at t = 0.98), 40 loses up to 0.16 % of real
#: points. A count, so independent of units; mind it when voxel filtering thins a cloud.
DEFAULT_MIN_POINTS = 10
#: How thoroughly the parts' boxes are searched (see :func:`decompose`).
PartSearch = Literal['light', 'full']
PART_SEARCHES: tuple[PartSearch, ...] = get_args(PartSearch)
#: Processing orders of the boxes waiting to be tested (see :func:`decompose`).
Order = Literal['volume', 'gain', 'breadth', 'depth']
ORDERS: tuple[Order, ...] = get_args(Order)
#: Why a node was not split (:attr:`DecompositionNode.stop_reason`).
StopReason = Literal['gain', 'no_cut', 'noise', 'max_boxes', 'dropped', 'thin']
STOP_REASONS: tuple[StopReason, ...] = get_args(StopReason)


def _integer(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f'{name} must be an integer >= {minimum}, got {value!r}')
    return int(value)


@dataclass(frozen=True)
class DecompositionSettings:
    """
    The arguments a decomposition was made with (validated; see :func:`decompose`).

    :raises ValueError: when a setting is out of range, with the setting's name and value.
    """

    gain_threshold: float = DEFAULT_GAIN_THRESHOLD
    min_points: int = DEFAULT_MIN_POINTS
    split_measure: splitting.SplitMeasure = 'area'
    rescore_cuts: int = 0
    max_boxes: int | None = None
    seed: int = 0
    grid_cells: int = splitting.DEFAULT_GRID_CELLS
    order: Order = 'volume'
    min_thickness: float = 0.0
    part_search: PartSearch = 'light'

    def __post_init__(self) -> None:
        threshold = self.gain_threshold
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float, np.number)):
            raise ValueError(f'gain_threshold must be a number in [0, 1], got {threshold!r}')
        if not 0.0 <= float(threshold) <= 1.0:
            raise ValueError(f'gain_threshold must be in [0, 1], got {threshold!r}')
        object.__setattr__(self, 'gain_threshold', float(threshold))
        object.__setattr__(self, 'min_points', _integer('min_points', self.min_points, 1))
        if self.split_measure not in splitting.SPLIT_MEASURES:
            raise ValueError(
                f'split_measure must be one of {splitting.SPLIT_MEASURES}, '
                f'got {self.split_measure!r}'
            )
        object.__setattr__(self, 'rescore_cuts', _integer('rescore_cuts', self.rescore_cuts, 0))
        if self.max_boxes is not None:
            object.__setattr__(self, 'max_boxes', _integer('max_boxes', self.max_boxes, 1))
        object.__setattr__(self, 'seed', _integer('seed', self.seed, 0))
        object.__setattr__(self, 'grid_cells', _integer('grid_cells', self.grid_cells, 2))
        if self.order not in ORDERS:
            raise ValueError(f'order must be one of {ORDERS}, got {self.order!r}')
        thickness = self.min_thickness
        if isinstance(thickness, bool) or not isinstance(thickness, (int, float, np.number)):
            raise ValueError(f'min_thickness must be a number >= 0, got {thickness!r}')
        if not 0.0 <= float(thickness) < math.inf:
            raise ValueError(f'min_thickness must be finite and >= 0, got {thickness!r}')
        object.__setattr__(self, 'min_thickness', float(thickness))
        if self.part_search not in PART_SEARCHES:
            raise ValueError(
                f'part_search must be one of {PART_SEARCHES}, got {self.part_search!r}'
            )


@dataclass(frozen=True, eq=False)
class DecompositionNode:
    """
    One box of the decomposition tree.

    :ivar index: position in :attr:`Decomposition.nodes` (0 is the root).
    :ivar box: the MVBB of the node's points.
    :ivar point_indices: sorted indices into :attr:`Decomposition.points` of the node's points.
    :ivar parent: index of the parent node, None for the root.
    :ivar children: indices of the child nodes, lower side of the cut first; empty unless the
        node was split. A child dropped as noise is listed too (its ``dropped`` is True).
    :ivar cut: the cut that split this node (see
        :class:`mvbb_ros.geometry.decomposition.split.Cut`), None when it was not split. The cut
        that made a node is its parent's ``cut``.
    :ivar tested_cut: the best cut found and tested for this node (``cut`` when it was split,
        the refused one when it was not); None when no cut was tested.
    :ivar theta: split measure theta of ``tested_cut`` (dimensionless), or None.
    :ivar gain: volume gain Theta* (eq. 2) of ``tested_cut`` (dimensionless), or None. For a
        split refused before its parts were fitted (with the volume of the other leaves, no
        child volumes could have brought Theta* below t), the lower bound that refused it:
        Theta* with children of no volume.
    :ivar depth: 0 for the root, the parent's depth + 1 otherwise.
    :ivar dropped: True when the node has fewer than ``min_points`` points and was removed as
        noise; its points are in :attr:`Decomposition.dropped_point_indices`.
    :ivar stop_reason: why a kept node was not split: ``'gain'`` (Theta* >= t), ``'no_cut'``
        (no cut splits its points in two with a finite theta: fewer than two distinct points, or
        all of them on a line), ``'noise'`` (both parts below ``min_points``), ``'max_boxes'``
        (the cap on leaves was reached); ``'dropped'`` for a dropped node; None for a split one.
    """

    index: int
    box: Box
    point_indices: IndexArray
    parent: int | None
    children: tuple[int, ...]
    cut: splitting.Cut | None
    tested_cut: splitting.Cut | None
    theta: float | None
    gain: float | None
    depth: int
    dropped: bool
    stop_reason: StopReason | None

    @property
    def is_leaf(self) -> bool:
        """Tell whether this is a kept box that was not split: a box of the approximation."""
        return not self.children and not self.dropped

    @property
    def point_count(self) -> int:
        """Return the number of points in the box."""
        return len(self.point_indices)

    def to_dict(self, *, include_point_indices: bool = False) -> dict[str, Any]:
        """
        Return the node as a JSON-ready dict.

        The box is its centre, quaternion (x, y, z, w), extents and volume; with the point
        count, parent, children, depth, cut, theta and Theta* (``gain``).

        :param include_point_indices: also list the node's point indices.
        :return: the dict.
        """
        data: dict[str, Any] = {
            'index': self.index,
            'parent': self.parent,
            'children': list(self.children),
            'depth': self.depth,
            'is_leaf': self.is_leaf,
            'dropped': self.dropped,
            'stop_reason': self.stop_reason,
            'point_count': self.point_count,
            'box': self.box.to_dict(),
            'theta': self.theta,
            'gain': self.gain,
            'cut': None if self.cut is None else self.cut.to_dict(),
            'tested_cut': None if self.tested_cut is None else self.tested_cut.to_dict(),
        }
        if include_point_indices:
            data['point_indices'] = [int(i) for i in self.point_indices]
        return data


@dataclass(frozen=True, eq=False)
class Decomposition:
    """
    The result of :func:`decompose`: the box tree over the input points.

    :ivar points: (N, 3) float64 input points (a read-only copy).
    :ivar nodes: every node in creation order; ``nodes[0]`` is the root and a node's children
        come after it.
    :ivar settings: the arguments used (:class:`DecompositionSettings`).
    """

    points: NDArray[np.float64]
    nodes: tuple[DecompositionNode, ...]
    settings: DecompositionSettings

    @property
    def root(self) -> DecompositionNode:
        """Return the root node: the MVBB of all input points."""
        return self.nodes[0]

    @property
    def leaf_nodes(self) -> list[DecompositionNode]:
        """Return the kept leaf nodes in node (creation) order."""
        return [node for node in self.nodes if node.is_leaf]

    @property
    def leaves(self) -> list[Box]:
        """Return the final boxes, the shape approximation, in node (creation) order."""
        return [node.box for node in self.leaf_nodes]

    @property
    def leaf_point_indices(self) -> list[IndexArray]:
        """Return the sorted point indices of each leaf, in the order of :attr:`leaves`."""
        return [node.point_indices for node in self.leaf_nodes]

    @property
    def dropped_point_indices(self) -> IndexArray:
        """Return the sorted indices of the points of boxes dropped as noise."""
        dropped = [node.point_indices for node in self.nodes if node.dropped]
        if not dropped:
            return np.empty(0, dtype=np.intp)
        return np.sort(np.concatenate(dropped))

    @property
    def kept_point_indices(self) -> IndexArray:
        """Return the sorted indices of the points in the leaves (all but the dropped ones)."""
        kept = self.leaf_point_indices
        if not kept:
            return np.empty(0, dtype=np.intp)
        return np.sort(np.concatenate(kept))

    @property
    def root_volume(self) -> float:
        """Return the volume of the root box (cubed units of the points)."""
        return self.root.box.volume

    @property
    def leaf_volume(self) -> float:
        """Return the summed volume of the leaf boxes (cubed units of the points)."""
        return math.fsum(box.volume for box in self.leaves)

    @property
    def volume_ratio(self) -> float:
        """Return leaf volume over root volume (scale-free; 1.0 for a flat root)."""
        root = self.root_volume
        return self.leaf_volume / root if root > 0.0 else 1.0

    def to_dict(self, *, include_point_indices: bool = False) -> dict[str, Any]:
        """
        Return the decomposition as a JSON-ready dict.

        Keys: ``settings``, ``point_count``, ``dropped_point_count``, ``root_volume``,
        ``leaf_volume``, ``leaves`` (the leaf node indices, in the order of :attr:`leaves`) and
        ``nodes`` (every node, see :meth:`DecompositionNode.to_dict`: box as centre, quaternion
        x y z w, extents and volume, point count, parent, children, cut, theta and Theta*).

        :param include_point_indices: also list every node's point indices.
        :return: the dict.
        """
        return {
            'settings': asdict(self.settings),
            'point_count': len(self.points),
            'dropped_point_count': len(self.dropped_point_indices),
            'root_volume': self.root_volume,
            'leaf_volume': self.leaf_volume,
            'leaves': [node.index for node in self.leaf_nodes],
            'nodes': [
                node.to_dict(include_point_indices=include_point_indices) for node in self.nodes
            ],
        }

    def to_json(self, indent: int | None = 2, *, include_point_indices: bool = False) -> str:
        """Return :meth:`to_dict` as a JSON string."""
        return json.dumps(self.to_dict(include_point_indices=include_point_indices), indent=indent)

    def __repr__(self) -> str:
        return (
            f'Decomposition({len(self.points)} points, {len(self.nodes)} nodes, '
            f'{len(self.leaf_nodes)} leaves, {len(self.dropped_point_indices)} dropped, '
            f'leaf/root volume {self.volume_ratio:.3f})'
        )
