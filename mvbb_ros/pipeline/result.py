"""
What the per-cloud pipeline returns: the objects, each decomposed, and the grasps on all of them.

:func:`~mvbb_ros.pipeline.process.process_points` makes a :class:`PipelineResult`, one
:class:`ObjectResult` per object; the node turns it into messages, `mvbb bag process` into a
bag and `mvbb decompose` into tables and JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mvbb_ros.arrays import IndexArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition.tree import Decomposition
from mvbb_ros.geometry.grasping.hypotheses import Grasp
from mvbb_ros.geometry.grasping.refine import RefinedGrasps
from mvbb_ros.geometry.views.completion import CompletedView
from mvbb_ros.pipeline.filtering import FilterCounts
from mvbb_ros.pipeline.scene import SupportPlane
from mvbb_ros.pipeline.view_edge import ViewEdge
import numpy as np


@dataclass(frozen=True, eq=False)
class ObjectResult:
    """
    One object of a cloud: its observed points, its estimated shape and its decomposition.

    :ivar index: the object's number in the cloud (0 is the largest).
    :ivar point_indices: the object's points among the filtered points (sorted; with a
        support plane, the filtered points of what stands on the table: the voxel grid and the
        outlier removal then run on those only).
    :ivar shape: the observed points and the estimate of the hidden side; the decomposition's
        points are ``shape.points``, observed first.
    :ivar decomposition: the fit-and-split tree of ``shape.points``.
    :ivar support_floor: the height along the up direction of the table the object rests on
        (from the support plane), or None when no plane was found under it.
    :ivar spacing: the distance between the object's neighbouring observed points (metres), as
        its completion and its grasps' surface used it.
    :ivar voxel_size: the voxel edge of the object's observed points (metres): a small object's
        own finer edge (``object_voxel_cells``, :mod:`mvbb_ros.pipeline.density`; its observed
        points are then not among the filtered points that `point_indices` indexes), else the
        frame's ``voxel_size``.
    :ivar view_edge: how far the object's filtered points stand from the view's edge, and
        whether the view cuts the object (:mod:`mvbb_ros.pipeline.view_edge`); None when not
        measured (no support plane, ``view_edge_margin_deg`` 0, or not one camera's view).
    """

    index: int
    point_indices: IndexArray
    shape: CompletedView
    decomposition: Decomposition
    support_floor: float | None = None
    spacing: float = 0.0
    voxel_size: float = 0.0
    view_edge: ViewEdge | None = None

    @property
    def cut_by_view(self) -> bool:
        """Tell whether the sensor saw the object only in part: its grasps come last."""
        return self.view_edge is not None and self.view_edge.cut

    @property
    def leaf_observed_counts(self) -> list[int]:
        """Return how many observed (not estimated) points each leaf holds."""
        observed = self.shape.observed
        return [
            int(np.count_nonzero(indices < observed))
            for indices in self.decomposition.leaf_point_indices
        ]


@dataclass
class PipelineResult:
    """
    What one cloud produced: its objects, each decomposed, and the grasps on all of them.

    `warning` says why the result is empty when the input could not be used (the node logs it,
    throttled, and publishes cleared outputs). Timings are wall-clock milliseconds per step.
    Boxes are numbered across objects: :attr:`leaves` lists every object's leaves in object
    order, and each grasp's ``box_index`` indexes it. `refinement` says what the refinement
    tried (None when it is off). `support` is the plane the objects stand on (None when the
    cloud is one segmented object, `support_note` says why); `up` the up direction the
    completion and the grasps used and `up_source` where it came from (``'up_direction'``,
    ``'support plane'`` or ``'none'``). `capped` says what a frame cap left out
    (``max_objects``). `units_note` says when the cloud looks like millimetres
    (:func:`~mvbb_ros.pipeline.process.millimetre_hint`); it never changes the result.
    `budget_note` says which settings the frame time budget lightened for this frame
    (:mod:`mvbb_ros.pipeline.budget`).
    """

    counts: FilterCounts
    objects: list[ObjectResult] = field(default_factory=list)
    grasps: list[Grasp] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)
    warning: str | None = None
    refinement: RefinedGrasps | None = None
    support: SupportPlane | None = None
    support_note: str | None = None
    up: tuple[float, float, float] | None = None
    up_source: str = 'none'
    capped: list[str] = field(default_factory=list)
    units_note: str | None = None
    budget_note: str | None = None

    @property
    def leaves(self) -> list[Box]:
        """Return every object's leaf boxes, in object order."""
        return [leaf for item in self.objects for leaf in item.decomposition.leaves]

    @property
    def leaf_object_indices(self) -> list[int]:
        """Return the object index of each of :attr:`leaves`."""
        return [item.index for item in self.objects for _ in item.decomposition.leaves]

    @property
    def leaf_observed_counts(self) -> list[int]:
        """Return how many observed points each of :attr:`leaves` holds."""
        return [count for item in self.objects for count in item.leaf_observed_counts]

    @property
    def cut_objects(self) -> list[int]:
        """Return the objects the view's edge cuts (their grasps come after the others')."""
        return [item.index for item in self.objects if item.cut_by_view]

    @property
    def inner_boxes(self) -> list[Box]:
        """Return every object's split (inner) boxes of the hierarchy, in object order."""
        return [
            node.box for item in self.objects for node in item.decomposition.nodes if node.children
        ]

    @property
    def inner_object_indices(self) -> list[int]:
        """Return the object index of each of :attr:`inner_boxes`."""
        return [
            item.index
            for item in self.objects
            for node in item.decomposition.nodes
            if node.children
        ]

    @property
    def notes(self) -> list[str]:
        """
        Return what to read the boxes with: units, time budget, frame caps, completions skipped.

        A completion asked for but skipped (the points are not one view from the viewpoint: a
        whole model, merged views, or a cloud transformed without setting ``viewpoint``) leaves
        boxes fitted to the points as they are, carved into plates on a single view.
        """
        units = [note for note in (self.units_note, self.budget_note) if note is not None]
        skipped = [
            f'object {item.index}: shape completion skipped, {item.shape.skipped}; its boxes '
            'fit the points as they are'
            for item in self.objects
            if item.shape.skipped is not None
        ]
        return units + self.capped + skipped

    @property
    def total_ms(self) -> float:
        """Return the total processing time in milliseconds."""
        return float(sum(self.timings_ms.values()))
