"""
The per-cloud pipeline: decode, filter, scene, objects, hidden side, decompose, grasp.

``docs/architecture.md`` follows one cloud through it.

One function, :func:`process_points` (behind :func:`process_cloud` for messages), serves the
node, `mvbb bag process` and `mvbb decompose`, with one :class:`PipelineSettings`, so a cloud
gives the same boxes and grasps live, offline and on the command line. What it returns is a
:class:`~mvbb_ros.pipeline.result.PipelineResult`. No ROS import: the cloud message is read
duck-typed (rclpy and rosbags messages both work).
"""

from __future__ import annotations

from dataclasses import asdict, replace
import time
from typing import Any

from mvbb_ros.arrays import column_max, column_min, column_span, FloatArray, IndexArray
from mvbb_ros.common.blas import one_blas_thread
from mvbb_ros.common.workers import Task, workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition.tree import decompose
from mvbb_ros.geometry.grasping.hypotheses import Grasp, grasp_hypotheses
from mvbb_ros.geometry.grasping.refine import refine_grasps
from mvbb_ros.geometry.grasping.refinement_settings import GraspView
from mvbb_ros.geometry.grasping.surface import surface_model, SurfaceModel
from mvbb_ros.geometry.views.cells import neighbour_distances
from mvbb_ros.geometry.views.completion import complete_view, CompletedView
from mvbb_ros.geometry.views.objects import separate_objects
from mvbb_ros.pipeline.budget import FrameBudget
from mvbb_ros.pipeline.decode import CloudFormatError, decode_points, Decoded
from mvbb_ros.pipeline.density import finer_object_points
from mvbb_ros.pipeline.filtering import (
    BackgroundFilter,
    crop_box,
    crop_points,
    filter_points,
    FilterCounts,
    finite_bounds,
    voxel_down_sample,
)
from mvbb_ros.pipeline.result import ObjectResult, PipelineResult
from mvbb_ros.pipeline.scene import (
    find_scene,
    roi_mask,
    Scene,
    standing_mask,
    SupportPlane,
)
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.pipeline.view_edge import cut_by_view, view_outline, ViewEdge
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: The cluster tolerance is at least this many point spacings (sparse clouds stay whole).
CLUSTER_SPACINGS = 3.0


def point_spacing(points: FloatArray, voxel_size: float) -> float:
    """
    Return the distance between neighbouring points, metres.

    The median nearest-neighbour distance of an evenly spread sample, and at least the voxel
    size. The neighbours are found along the points sorted on their widest axis
    (:func:`~mvbb_ros.geometry.views.cells.neighbour_distances`: a k-d tree's distances, cheaper
    for a few hundred queries).
    """
    array = np.ascontiguousarray(points, dtype=np.float64)
    sample = np.arange(0, len(array), max(1, len(array) // 256))
    axis = int(np.argmax(column_span(array))) if len(array) else 0
    order = np.argsort(array[:, axis])
    distances = neighbour_distances(array, order, axis, sample)
    spacing = max(float(np.median(distances)), voxel_size)
    if spacing > 0.0:
        return spacing
    extent = float(np.max(column_span(points)))
    return extent / 100.0 if extent > 0.0 else 1.0


#: The scene stage's grid needs the spacing only roughly: measured on at most this many points.
SPACING_SAMPLE = 20_000


def spacing_estimate(points: FloatArray, voxel_size: float, sample: int = SPACING_SAMPLE) -> float:
    """
    Return about :func:`point_spacing` of `points` (a surface), measured on about `sample`.

    A surface sampled k times more sparsely has its points about sqrt(k) times farther apart.
    """
    step = max(1, len(points) // sample)
    if step == 1:
        return point_spacing(points, voxel_size)
    return max(point_spacing(points[::step], 0.0) / float(np.sqrt(step)), voxel_size)


#: A large cloud's table is looked for on every k-th of its points, about this many.
SCENE_SAMPLE = 16384
#: The scene stage's grid of the table needs the spacing only roughly: measured on at most
#: this many points of its sample.
SCENE_SPACING_SAMPLE = 4096


def scene_sample(points: NDArray[np.floating], voxel_size: float) -> FloatArray:
    """
    Return the voxel grid of every k-th of `points`, k = ``len(points) // SCENE_SAMPLE``.

    The scene stage's plane, outline and decision need only a sample of a large cloud (a
    camera frame's rows give evenly spread points); what stands on the table is then taken from
    all points. The voxel grid keeps the sample's density that of the filtered points, so a
    dense small cloud (k = 1: the voxel grid of all its points, as without the sample) is
    judged on the same points as before.
    """
    step = max(1, len(points) // SCENE_SAMPLE)
    return voxel_down_sample(points[::step], voxel_size)[0]


def _empty_counts(count: int = 0) -> FilterCounts:
    return FilterCounts(count, count, count, count)


#: A segmented object in metres is smaller than this along every axis (metres); a wider cloud
#: is rejected before any filter (a voxel grid on it would not fit 64-bit indices).
MAX_EXTENT_M = 1000.0
#: The units hint: a cloud wider than this (metres) along some axis ...
MM_SPAN_M = 10.0
#: ... whose neighbouring points lie farther apart than this (metres) looks like millimetres.
MM_SPACING_M = 0.25
#: A cloud too wide to be one object that would span at most this (metres) in millimetres
#: (a robot's workspace) gets the millimetres hint in its rejection.
MM_WORKSPACE_M = 10.0


def millimetre_hint(span: ArrayLike, spacing: float) -> str | None:
    """
    Return a note when a cloud looks like millimetres read as metres, else None.

    The rule: wider than :data:`MM_SPAN_M` along some axis and a point spacing (median
    neighbour distance) above :data:`MM_SPACING_M`. A graspable object in millimetres spans
    tens to hundreds of "metres" with points about a "metre" apart; a depth camera or a laser
    scanner in metres gives spacings of millimetres, a LiDAR scene of centimetres to a
    decimetre. A hint only: the pipeline's answer is the same with or without it.

    :param span: the cloud's extent along x, y, z (metres as given).
    :param spacing: the median distance between neighbouring points (metres as given).
    """
    extent = np.asarray(span, dtype=np.float64).reshape(3)
    if not (float(extent.max()) > MM_SPAN_M and spacing > MM_SPACING_M):
        return None
    spans = ' x '.join(f'{v:.3g}' for v in extent)
    scaled = ' x '.join(f'{v / 1000.0:.3g}' for v in extent)
    return (
        f'looks like millimetres: the points span {spans} m and lie {spacing:.3g} m apart; '
        f'in millimetres that is {scaled} m. Scale the cloud by 0.001 if so'
    )


def units_hint(points: NDArray[np.floating], bounds: ArrayLike | None = None) -> str | None:
    """
    Return :func:`millimetre_hint` for finite `points` (N, 3), or None.

    The spacing is measured (on a sample, :func:`spacing_estimate`) only for clouds wider than
    :data:`MM_SPAN_M`, so an object-sized cloud costs nothing here.

    :param bounds: ``(2, 3)`` min and max corners of the points when known; None measures them.
    """
    if len(points) < 2:
        return None
    if bounds is None:
        span = column_span(points).astype(np.float64)
    else:
        corners = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        span = corners[1] - corners[0]
    if not float(span.max()) > MM_SPAN_M:
        return None
    return millimetre_hint(span, spacing_estimate(np.asarray(points, dtype=np.float64), 0.0))


def implausible_extent(
    points: NDArray[np.floating], bounds: ArrayLike | None = None
) -> str | None:
    """
    Return why finite `points` (N, 3) cannot be one object in metres, or None when they can.

    A cloud of random bytes (coordinates up to 3.4e38), a cloud in the wrong units or a whole
    map spans more than :data:`MAX_EXTENT_M` along some axis; the pipeline rejects it with
    this reason instead of failing deep inside a filter. Where the object is does not matter.

    :param points: the points.
    :param bounds: ``(2, 3)`` min and max corners of the points when known (the decoder measures
        them, after its crop: a crop box that keeps one object out of a whole map makes it
        plausible); None measures them here.
    :return: the reason, or None.
    """
    if len(points) == 0:
        return None
    if bounds is None:
        # In float64: float32 extremes (random bytes) would overflow to inf in the message.
        extent = column_max(points).astype(np.float64) - column_min(points).astype(np.float64)
    else:
        corners = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        extent = corners[1] - corners[0]
    if extent.max() <= MAX_EXTENT_M:
        return None
    spans = ' x '.join(f'{v:.3g}' for v in extent)
    hint = ''
    if extent.max() <= MM_WORKSPACE_M * 1000.0:
        scaled = ' x '.join(f'{v / 1000.0:.3g}' for v in extent)
        hint = f'; looks like millimetres: in millimetres that is {scaled} m'
    return (
        f'absurd cloud: its points span {spans} m, more than {MAX_EXTENT_M:g} m; not a '
        f'segmented object in metres (random bytes, wrong units or a whole map?){hint}'
    )


def process_points(
    points: ArrayLike,
    settings: PipelineSettings | None = None,
    timings_ms: dict[str, float] | None = None,
    decoded: Decoded | None = None,
    *,
    previous: Grasp | None = None,
) -> PipelineResult:
    """
    Filter, decompose and grasp finite `points` (N, 3) in metres.

    :param points: finite points of one segmented object, in the sensor frame (float32 or
        float64).
    :param settings: the pipeline settings; None for the node's defaults (``PipelineSettings()``;
        ``PipelineSettings.paper()`` is the paper's algorithm).
    :param timings_ms: step timings measured before this call (decoding), kept in the result.
    :param decoded: what the decoder measured when `points` are its ``decoded.points``, already
        cropped to the settings' crop box (:func:`process_cloud`): their bounds and the finite
        count, which spare the filters a pass over the points.
    :param previous: the top grasp of the previous cloud of the same stream, in the same frame
        (None for a first cloud): with the refinement on, it stays on top while it still holds
        and scores within ``grasp_hysteresis`` of the best (``docs/grasp_rules.md``).
    :return: the result; empty with a `warning` when the points cannot be one object in
        metres (:func:`implausible_extent`) or too few points remain.

    OpenBLAS runs on one thread meanwhile (:mod:`mvbb_ros.common.blas`): the workers are the
    pipeline's threads.
    """
    with one_blas_thread():
        return _process_points(points, settings, timings_ms, decoded, previous)


def _process_points(
    points: ArrayLike,
    settings: PipelineSettings | None,
    timings_ms: dict[str, float] | None,
    decoded: Decoded | None,
    previous: Grasp | None,
) -> PipelineResult:
    """:func:`process_points` itself (OpenBLAS already on one thread)."""
    settings = settings if settings is not None else PipelineSettings()
    count = settings.execution.workers
    pool = None if count == 1 else workers(count)
    timings = dict(timings_ms or {})
    start = time.perf_counter()
    array = np.asarray(points)
    bounds = None if decoded is None else decoded.bounds
    finite = None if decoded is None else decoded.finite
    # The corners the checks below need, measured once (the decoder's when it measured them).
    corners = bounds if bounds is not None or len(array) == 0 else finite_bounds(array)
    reason = implausible_extent(array, corners)
    if reason is not None:
        count = len(array) if decoded is None else decoded.finite
        return PipelineResult(counts=_empty_counts(count), timings_ms=timings, warning=reason)
    units_note = units_hint(array, corners)
    if (
        decoded is None
        and corners is not None
        and array.dtype in (np.float32, np.float64)
        and array.ndim == 2
        and array.shape[1] == 3
        and not crop_box(settings.filtering.crop_min, settings.filtering.crop_max)[1]
    ):
        # No crop box: the corners just measured are what the decoder would have given (every
        # point finite, none cropped), so the voxel grid does not measure them again.
        bounds, finite = corners, len(array)
    near = roi_mask(array, settings.view.viewpoint, settings.scene.roi_max_distance, corners)
    if near is not None:
        # The region of interest before the filters: a room-sized cloud shrinks first. The rows
        # by np.compress: numpy's boolean row index takes 5 x as long on 300k points.
        array, bounds, finite = np.compress(near, array, axis=0), None, None
    filtering = settings.filtering
    min_points = settings.decomposition.min_points
    view = settings.view
    scene = Scene(None, None, 'support_plane: none')
    # What the voxel grid was made of (the cropped cloud, or what stands on the table): small
    # objects take their points from it again, finer (:mod:`mvbb_ros.pipeline.density`).
    raw: NDArray[np.floating] | None = None
    # The frame as the scene stage saw it (its sample): the view's outline is measured on it.
    frame: NDArray[np.floating] | None = None
    if settings.scene.support_plane != 'none' and filtering.voxel_size > 0.0:
        # The table first, on a sample of the points; then the filters on what stands on it
        # only, not on the whole room. Without a table the cloud is filtered as without the
        # scene stage, from the start.
        start = time.perf_counter()
        unfiltered: BackgroundFilter | None = None
        if pool is not None:
            # A cloud without a table (a segmented object) is filtered whole: its voxel grid and
            # outlier queries start now, on a helper, while this thread looks for the table
            # (then shares the queries left); a table drops them.
            unfiltered = BackgroundFilter(pool, array, filtering, bounds=bounds, finite=finite)
        scoped = array
        if bounds is None:  # not cropped by the decoder
            scoped = crop_points(array, filtering.crop_min, filtering.crop_max)
        raw = scoped
        sample = frame = scene_sample(scoped, filtering.voxel_size)
        if len(sample) >= min_points:
            scene = find_scene(
                sample,
                settings.scene,
                viewpoint=view.viewpoint,
                up=view.up,
                spacing=spacing_estimate(sample, filtering.voxel_size, SCENE_SPACING_SAMPLE),
                min_points=min_points,
            )
        timings['scene'] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        if scene.support is None and unfiltered is not None:
            filtered, counts = unfiltered.result()
        elif scene.support is None:
            filtered, counts = filter_points(
                array, bounds=bounds, finite=finite, pool=pool, **asdict(filtering)
            )
        else:
            if unfiltered is not None:
                unfiltered.cancel()
            on_table = standing_mask(scoped, scene.support, settings.scene)
            standing_points = np.compress(on_table, scoped, axis=0)
            uncropped = replace(filtering, crop_min=(), crop_max=())
            filtered, counts = filter_points(standing_points, pool=pool, **asdict(uncropped))
            raw = standing_points
            whole = len(array) if finite is None else finite
            counts = replace(counts, finite=int(whole), cropped=len(scoped))
        timings['filter'] = (time.perf_counter() - start) * 1e3
    else:
        filtered, counts = filter_points(
            array, bounds=bounds, finite=finite, pool=pool, **asdict(filtering)
        )
        timings['filter'] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        if settings.scene.support_plane != 'none' and len(filtered) >= min_points:
            scene = find_scene(
                filtered,
                settings.scene,
                viewpoint=view.viewpoint,
                up=view.up,
                spacing=spacing_estimate(filtered, filtering.voxel_size),
                min_points=min_points,
            )
            if scene.kept is not None:
                frame, filtered = filtered, filtered[scene.kept]
        timings['scene'] = (time.perf_counter() - start) * 1e3
    if near is not None:
        counts = replace(counts, finite=int(len(near) if decoded is None else decoded.finite))
    if raw is None and filtering.voxel_size > 0.0 and view.object_voxel_cells > 0:
        raw = (
            array
            if bounds is not None
            else crop_points(array, filtering.crop_min, filtering.crop_max)
        )
    support = scene.support
    if support is not None and len(filtered) < min_points:
        warning = (
            f'only {len(filtered)} points stand on the support plane, fewer than '
            f'min_points = {min_points}'
        )
        return PipelineResult(
            counts=counts,
            timings_ms=timings,
            warning=warning,
            support=support,
            units_note=units_note,
        )
    if len(filtered) < min_points:
        warning = (
            f'only {len(filtered)} of {counts.finite} points left after filtering, fewer than '
            f'min_points = {min_points}'
        )
        return PipelineResult(
            counts=counts, timings_ms=timings, warning=warning, units_note=units_note
        )
    start = time.perf_counter()
    standing = filtered
    spacing = point_spacing(standing, filtering.voxel_size)
    up: ArrayLike | None = view.up
    up_source = 'up_direction'
    if up is None:
        up, up_source = (None, 'none') if support is None else (support.normal, 'support plane')
    timings['scene'] += (time.perf_counter() - start) * 1e3

    def empty(warning: str | None) -> PipelineResult:
        return PipelineResult(
            units_note=units_note,
            counts=counts,
            timings_ms=timings,
            warning=warning,
            support=support,
            support_note=scene.reason,
            up=None if up is None else _unit(up),
            up_source=up_source,
        )

    start = time.perf_counter()
    # A tolerance below the point spacing would cut every object into single points.
    tolerance = max(view.cluster_tolerance, CLUSTER_SPACINGS * spacing)
    groups = separate_objects(
        standing,
        tolerance if view.cluster_tolerance > 0.0 else 0.0,
        viewpoint=view.viewpoint,
        spacing=spacing,
        min_points=min_points,
        support=None if support is None else support.coefficients,
        clearance=settings.scene.support_distance,
    )
    timings['objects'] = (time.perf_counter() - start) * 1e3
    if not groups:
        return empty(f'no object of at least min_points = {min_points} points in the cloud')

    capped = []
    if 0 < view.max_objects < len(groups):
        left_out = sum(len(group) for group in groups[slice(view.max_objects, None)])
        capped.append(
            f'max_objects: kept the {view.max_objects} largest of {len(groups)} objects '
            f'({left_out} points left out)'
        )
        groups = groups[: view.max_objects]
    timings['completion'] = timings['decompose'] = 0.0
    refining = settings.refinement.enabled
    start = time.perf_counter()
    edges = _view_edges(frame, scene, standing, groups, settings, tolerance)
    timings['scene'] += (time.perf_counter() - start) * 1e3  # the view's edge: the scene's

    def one_object(index: int) -> tuple[ObjectResult, Task[SurfaceModel] | None, float, float]:
        start = time.perf_counter()
        members = groups[index]
        observed = standing[members]
        object_spacing, object_voxel = spacing, filtering.voxel_size
        finer = None
        if raw is not None:
            finer = finer_object_points(
                observed,
                raw,
                filtering.voxel_size,
                view.object_voxel_cells,
                view.min_voxel_size,
                filtering.outlier_neighbors,
                filtering.outlier_std_ratio,
            )
        if finer is not None:
            observed, object_voxel = finer.points, finer.voxel_size
            object_spacing = point_spacing(observed, object_voxel)
        floor = None if support is None or up is None else resting_floor(observed, support, up)
        shape = complete_view(
            observed,
            method=view.completion,
            viewpoint=view.viewpoint,
            up=up,
            spacing=object_spacing,
            floor=floor,
            pool=pool,
        )
        completion_ms = (time.perf_counter() - start) * 1e3
        surface = None
        if pool is not None and refining and shape.method != 'none':
            # The refinement's surface needs the shape only: made while the shape decomposes.
            surface = pool.submit(lambda: shape_surface(shape, floor, object_spacing, up))
        start = time.perf_counter()
        decomposition = decompose(shape.points, pool=pool, **asdict(settings.decomposition))
        decompose_ms = (time.perf_counter() - start) * 1e3
        item = ObjectResult(
            index,
            members,
            shape,
            decomposition,
            floor,
            object_spacing,
            object_voxel,
            view_edge=edges[index],
        )
        return item, surface, completion_ms, decompose_ms

    if pool is None:
        done = [one_object(index) for index in range(len(groups))]
    else:
        # Objects at once, in order; each object's own fits and surface use the rest.
        done = pool.spread(one_object, range(len(groups)))
    objects = [item for item, *_ in done]
    if any(item.shape.skipped is not None for item in objects):
        # Not one view from `viewpoint` (the completion said so): no view's edge either.
        objects = [replace(item, view_edge=None) for item in objects]
    surfaces = [surface for _, surface, *_ in done]
    for _, _, completion_ms, decompose_ms in done:
        timings['completion'] += completion_ms
        timings['decompose'] += decompose_ms

    start = time.perf_counter()
    result = empty(None)
    result.objects = objects
    result.capped = capped
    options = asdict(settings.grasps)
    if refining:
        options['max_grasps'] = 0  # every hypothesis is a seed
    if support is not None and options['support_plane'] is None:
        options['support_plane'] = support.coefficients  # no approach through the table
    timings['grasps'] = 0.0

    cut = [item.index for item in objects if item.cut_by_view]
    limit = options['max_grasps']
    if cut and not refining:
        options['max_grasps'] = 0  # all of them, then the whole objects' first

    def hypotheses() -> list[Grasp]:
        begin = time.perf_counter()
        made = grasp_hypotheses(
            result.leaves,
            up=up,
            sensor_origin=view.viewpoint,
            object_indices=result.leaf_object_indices,
            **options,
        )
        if cut and not refining:
            made.sort(key=lambda grasp: grasp.object_index in cut)  # stable
            made = made[:limit] if limit > 0 else made
        timings['grasps'] = (time.perf_counter() - begin) * 1e3
        return made

    if not refining:
        result.grasps = hypotheses()
        return result
    models = [
        object_surface(item, item.spacing, up) if surface is None else surface.result()
        for item, surface in zip(objects, surfaces, strict=True)
    ]
    # The hypotheses are made while the helpers check the boxes' own lines (the refinement's).
    result.refinement = refine_grasps(
        hypotheses,
        result.leaves,
        result.leaf_object_indices,
        models,
        settings.refinement,
        grasp_view(settings, up),
        previous,
        pool=pool,
        deferred=cut,
    )
    result.grasps = result.refinement.grasps
    timings['refine'] = (time.perf_counter() - start) * 1e3 - timings['grasps']
    return result


def _view_edges(
    frame: NDArray[np.floating] | None,
    scene: Scene,
    points: FloatArray,
    groups: list[IndexArray],
    settings: PipelineSettings,
    tolerance: float,
) -> list[ViewEdge | None]:
    """
    Return how far each object (`groups` of `points`) stands from the view's edge, or Nones.

    Measured only on a scene frame (`scene` found its support on `frame`, the points the scene
    stage looked at) with ``view_edge_margin_deg`` on (:mod:`mvbb_ros.pipeline.view_edge`).
    `tolerance` is the objects' cluster tolerance (metres).
    """
    margin = settings.view.view_edge_margin_deg
    support = scene.support
    if frame is None or support is None or scene.kept is None or margin <= 0.0:
        return [None] * len(groups)
    outline = view_outline(frame, settings.view.viewpoint)
    if outline is None:
        return [None] * len(groups)
    # What the table's outline strip dropped above the table: it may hide where the view cuts
    # an object that stands at the table's edge.
    stage = settings.scene
    band = standing_mask(frame, support, replace(stage, support_margin=0.0))
    band[scene.kept] = False
    strip = np.compress(band, frame, axis=0)
    reach = stage.support_margin + tolerance
    return [cut_by_view(outline, points[members], margin, strip, reach) for members in groups]


def _unit(vector: ArrayLike) -> tuple[float, float, float]:
    unit = np.asarray(vector, dtype=np.float64)
    x, y, z = (unit / np.linalg.norm(unit)).tolist()
    return x, y, z


#: An object whose lowest point is at most this far above the support plane (metres) rests on
#: it: its hidden side is filled down to the table.
RESTING_GAP = 0.05


def resting_floor(points: FloatArray, support: SupportPlane, up: ArrayLike) -> float | None:
    """
    Return the height along unit `up` of the table under `points`, or None when not resting.

    Each point is taken straight down (along -`up`) to the support plane; the floor is the mean
    height there, when the object's lowest point is within :data:`RESTING_GAP` of the plane.
    """
    heights = support.heights(points)
    if float(heights.min()) > RESTING_GAP:
        return None
    unit = np.asarray(up, dtype=np.float64)
    slope = float(support.normal @ unit)
    if slope <= 0.1:
        return None
    return float(np.mean(points @ unit - heights / slope))


def grasp_view(settings: PipelineSettings, up: ArrayLike | None) -> GraspView:
    """
    Return what the refinement needs of the gripper and the view, from the settings.

    `up` is the up direction the pipeline uses (``up_direction``, else the support plane's
    normal), or None.
    """
    grasps, view = settings.grasps, settings.view
    up = None if up is None else np.asarray(_unit(up))
    return GraspView(
        gripper_max_width=grasps.gripper_max_width,
        standoff=grasps.standoff,
        approach_axis=grasps.approach_axis,
        strategy=grasps.strategy,
        up=up,
        viewpoint=np.asarray(view.viewpoint, dtype=np.float64),
        far_side=grasps.far_side,
        max_approach_elevation_deg=grasps.max_approach_elevation_deg,
        support_clearance=settings.refinement.support_clearance,
        max_grasps=grasps.max_grasps,
    )


def object_surface(item: ObjectResult, spacing: float, up: ArrayLike | None) -> SurfaceModel:
    """
    Return the surface of one object for the refinement: its observed and estimated points.

    When nothing was asked to estimate the hidden side (``shape_completion: none``), the
    object's leaf boxes stand for it: their volume is sampled every `spacing`.
    """
    shape = item.shape
    if shape.method == 'none' and item.decomposition.leaves:
        filled = [box_samples(box, spacing) for box in item.decomposition.leaves]
        points = np.concatenate([shape.points, *filled])
        return surface_model(
            points, observed=shape.observed, cell=spacing, up=up, support_floor=item.support_floor
        )
    return shape_surface(shape, item.support_floor, spacing, up)


def shape_surface(
    shape: CompletedView, floor: float | None, spacing: float, up: ArrayLike | None
) -> SurfaceModel:
    """Return the surface of an object's shape (its observed and estimated points)."""
    return surface_model(
        shape.points, observed=shape.observed, cell=spacing, up=up, support_floor=floor
    )


#: The most samples of one box's volume (coarser beyond).
MAX_BOX_SAMPLES = 20_000


def box_samples(box: Box, step: float) -> FloatArray:
    """Return points filling `box` on a grid every `step` (coarser for very large boxes)."""
    cells = np.prod(np.maximum(box.extents / step, 1.0))
    if cells > MAX_BOX_SAMPLES:
        step *= (cells / MAX_BOX_SAMPLES) ** (1.0 / 3.0)
    axes = [
        np.linspace(-half, half, max(2, int(np.ceil(2.0 * half / step)) + 1))
        for half in box.half_extents
    ]
    grid = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    return box.to_world(grid)


def decode_cloud(cloud: Any, settings: PipelineSettings | None = None) -> Decoded:
    """
    Decode a PointCloud2 (rclpy or rosbags message) to finite (N, 3) points, cropped.

    float32 when the cloud's x, y, z are float32 (no float64 copy of a whole frame: the filter
    takes float32 as it is), float64 otherwise; the settings' crop box is applied while
    decoding. See :func:`mvbb_ros.pipeline.decode.decode_points`.
    """
    filtering = (settings if settings is not None else PipelineSettings()).filtering
    return decode_points(cloud, crop_min=filtering.crop_min, crop_max=filtering.crop_max)


def process_cloud(
    cloud: Any,
    settings: PipelineSettings,
    *,
    previous: Grasp | None = None,
    budget: FrameBudget | None = None,
) -> PipelineResult:
    """
    Run the whole pipeline on one `sensor_msgs/PointCloud2` (never modified).

    A malformed cloud gives an empty result whose `warning` says what is wrong. `previous` is
    the previous cloud's top grasp, as for :func:`process_points` (:class:`GraspMemory` keeps
    it). `budget` is the stream's frame time budget: the frame runs with the settings it gives
    (lighter after frames over ``frame_time_budget``, the result's `budget_note` says how) and
    its time is recorded in it.
    """
    if budget is None:
        return _process_cloud(cloud, settings, previous)
    lighter, note = budget.settings(settings)
    result = _process_cloud(cloud, lighter, previous)
    result.budget_note = note
    budget.record(result.total_ms / 1e3)
    return result


def _process_cloud(
    cloud: Any, settings: PipelineSettings, previous: Grasp | None
) -> PipelineResult:
    start = time.perf_counter()
    try:
        decoded = decode_cloud(cloud, settings)
    except CloudFormatError as error:
        return PipelineResult(counts=_empty_counts(), warning=f'malformed cloud: {error}')
    timings = {'decode': (time.perf_counter() - start) * 1e3}
    if decoded.finite == 0:
        return PipelineResult(
            counts=_empty_counts(), timings_ms=timings, warning='cloud has no finite points'
        )
    return process_points(decoded.points, settings, timings, decoded, previous=previous)


class GraspMemory:
    """
    The top grasp of the last cloud of a stream, for the hysteresis of the next one.

    The node and `mvbb bag process` keep one: :meth:`previous` gives the last top grasp when the
    new cloud is in the same frame (a grasp in another frame means nothing there), and
    :meth:`remember` stores the new result's top grasp (none after a cloud without grasps, so
    the next cloud starts afresh).
    """

    def __init__(self) -> None:
        self._frame: str | None = None
        self._grasp: Grasp | None = None

    def previous(self, frame_id: str) -> Grasp | None:
        """Return the last top grasp if it was found in frame `frame_id`, else None."""
        return self._grasp if frame_id == self._frame else None

    def remember(self, frame_id: str, result: PipelineResult | None) -> None:
        """Keep `result`'s top grasp (or nothing) as the previous one for frame `frame_id`."""
        self._frame = frame_id
        self._grasp = result.grasps[0] if result is not None and result.grasps else None
