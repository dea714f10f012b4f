"""
The settings of the pipeline layer's own stages: filtering, the view, execution and the node.

Frozen dataclasses whose defaults are the library's own: "off" for the filters, the paper's one
segmented object seen from the frame's origin for the view.
:class:`~mvbb_ros.pipeline.settings.PipelineSettings` composes them with the scene's and the
geometry's. They are defined apart from the stages' code, so that reading the settings does not
load Open3D, which the filters use. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import get_args, Literal

from mvbb_ros.common.workers import default_workers
from mvbb_ros.geometry.views.completion import Completion

#: The default worker count of this process (:func:`~mvbb_ros.common.workers.default_workers`:
#: its cores, at most 8), fixed at import.
DEFAULT_WORKERS = default_workers()


@dataclass(frozen=True)
class FilterSettings:
    """
    The settings of the filtering stage (the keyword arguments of ``filter_points``).

    :func:`~mvbb_ros.pipeline.filtering.filter_points` crops, voxel-filters and removes
    outliers. The defaults turn every filter off, as in the paper (which filters nothing); the
    node's defaults (``config/decomposer.yaml``) turn the voxel grid and the outlier removal on.
    """

    crop_min: tuple[float, ...] = ()
    crop_max: tuple[float, ...] = ()
    voxel_size: float = 0.0
    outlier_neighbors: int = 0
    outlier_std_ratio: float = 2.0


#: Reliability of the node's input (the ``input_reliability`` setting); the first is the
#: default: ``auto`` is reliable when every publisher of the input offers reliable delivery.
InputReliability = Literal['auto', 'reliable', 'best_effort']
INPUT_RELIABILITIES: tuple[InputReliability, ...] = get_args(InputReliability)


@dataclass(frozen=True)
class ViewSettings:
    """
    What is known of the sensor view, and how the view becomes objects' shapes.

    The defaults are the paper's: the frame's origin as the sensor, no up direction, the whole
    cloud one object, the observed points alone. The node's defaults (``config/decomposer.yaml``)
    separate objects and complete their hidden side (``docs/single_views.md``).

    :ivar viewpoint: (3,) sensor position in the cloud's frame, metres (the frame's origin for
        camera and laser frames; set it for clouds transformed into another frame).
    :ivar up: up direction in the cloud's frame, or None when unknown: vertical mirror planes,
        a support below the object, and no grasps from below.
    :ivar cluster_tolerance: points closer than this (metres) are one object; 0 keeps the
        whole cloud as one object (:func:`~mvbb_ros.geometry.views.objects.separate_objects`).
    :ivar completion: how each object's hidden side is estimated
        (:func:`~mvbb_ros.geometry.views.completion.complete_view`).
    :ivar max_objects: the largest objects of a frame that are decomposed and grasped; the
        others are left out and the result says so (0: all). With ``max_boxes`` it bounds the
        boxes, and so the grasps, of a whole frame.
    :ivar object_voxel_cells: with the voxel grid on, an object smaller than this many voxels
        across takes its points again from the cloud at its largest extent over this many
        (:mod:`mvbb_ros.pipeline.density`); 0: every object keeps the frame's voxel grid.
    :ivar min_voxel_size: the finest voxel edge an object gets (metres).
    :ivar view_edge_margin_deg: on a scene frame (a support plane found), an object whose
        points come closer than this to the frame's outline as the sensor sees it (degrees) is
        cut by the view's edge: its grasps come after those of whole objects
        (:mod:`mvbb_ros.pipeline.view_edge`); 0: no object is.
    """

    viewpoint: tuple[float, ...] = (0.0, 0.0, 0.0)
    up: tuple[float, ...] | None = None
    cluster_tolerance: float = 0.0
    completion: Completion = 'none'
    max_objects: int = 0
    object_voxel_cells: int = 0
    min_voxel_size: float = 0.002
    view_edge_margin_deg: float = 0.0


@dataclass(frozen=True)
class ExecutionSettings:
    """
    How the pipeline runs: on how many threads. The results are the same with any.

    :ivar workers: threads that run the compiled kernels of one cloud (the calling thread and
        ``workers - 1`` helpers, :mod:`mvbb_ros.common.workers`); 1 runs everything on the
        calling thread. The default is the cores this process may use, at most
        :data:`~mvbb_ros.common.workers.MAX_DEFAULT_WORKERS`.
    """

    workers: int = DEFAULT_WORKERS


@dataclass(frozen=True)
class NodeSettings:
    """
    The settings of the node itself, beyond the pipeline's stages.

    :ivar publish_tree: also publish the non-leaf boxes of the hierarchy on ``~/tree``.
    :ivar input_reliability: the input's reliability: ``auto`` (matched to the publishers),
        ``reliable`` or ``best_effort``.
    :ivar input_depth: the input's queue (keep last `input_depth`; 1: always the newest cloud).
    :ivar stale_after: seconds without a cloud after which the diagnostics warn (0: never).
    :ivar frame_time_budget: seconds of pipeline time per frame; after frames that took
        longer, the next frames run with lighter settings (:mod:`mvbb_ros.pipeline.budget`);
        0: off.
    """

    publish_tree: bool = True
    input_reliability: InputReliability = 'auto'
    input_depth: int = 1
    stale_after: float = 5.0
    frame_time_budget: float = 0.0
