"""
The per-cloud pipeline: decode, filter, decompose, grasp (``docs/architecture.md``).

One function, :func:`process_points` (behind :func:`process_cloud` for messages), serves the
node, `mvbb bag process` and `mvbb decompose`, with one :class:`PipelineSettings`, so a cloud
gives the same boxes and grasps live, offline and on the command line. No ROS import: the cloud
message is read duck-typed (rclpy and rosbags messages both work).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import time
from typing import Any

from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition import decompose, Decomposition
from mvbb_ros.geometry.grasps import Grasp, grasp_hypotheses
from mvbb_ros.pipeline.decode import CloudFormatError, read_points
from mvbb_ros.pipeline.filtering import filter_points, FilterCounts
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass
class PipelineResult:
    """
    What one cloud produced.

    `warning` says why the result is empty when the input could not be used (the node logs it,
    throttled, and publishes cleared outputs). Timings are wall-clock milliseconds per step.
    """

    counts: FilterCounts
    decomposition: Decomposition | None = None
    grasps: list[Grasp] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)
    warning: str | None = None

    @property
    def leaves(self) -> list[Box]:
        """Return the leaf boxes (empty when there is no decomposition)."""
        return [] if self.decomposition is None else list(self.decomposition.leaves)

    @property
    def leaf_object_indices(self) -> list[int]:
        """Return the object index of each of :attr:`leaves` (one object: all 0)."""
        return [0] * len(self.leaves)

    @property
    def total_ms(self) -> float:
        """Return the total processing time in milliseconds."""
        return float(sum(self.timings_ms.values()))


def _empty_counts(count: int = 0) -> FilterCounts:
    return FilterCounts(count, count, count, count)


#: A segmented object in metres is smaller than this along every axis (metres); a wider cloud
#: is rejected before any filter (a voxel grid on it would not fit 64-bit indices).
MAX_EXTENT_M = 1000.0


def implausible_extent(points: NDArray[np.floating]) -> str | None:
    """
    Return why finite `points` (N, 3) cannot be one object in metres, or None when they can.

    A cloud of random bytes (coordinates up to 3.4e38), a cloud in the wrong units or a whole
    map spans more than :data:`MAX_EXTENT_M` along some axis; the pipeline rejects it with
    this reason instead of failing deep inside a filter. Where the object is does not matter.
    """
    if len(points) == 0:
        return None
    extent = points.max(axis=0).astype(np.float64) - points.min(axis=0).astype(np.float64)
    if extent.max() <= MAX_EXTENT_M:
        return None
    spans = ' x '.join(f'{v:.3g}' for v in extent)
    return (
        f'absurd cloud: its points span {spans} m, more than {MAX_EXTENT_M:g} m; not a '
        'segmented object in metres (random bytes, wrong units or a whole map?)'
    )


def process_points(
    points: ArrayLike,
    settings: PipelineSettings | None = None,
    timings_ms: dict[str, float] | None = None,
) -> PipelineResult:
    """
    Filter, decompose and grasp finite `points` (N, 3) in metres.

    :param points: finite points of one segmented object, in the sensor frame (float32 or
        float64).
    :param settings: the pipeline settings; None for the node's defaults (``PipelineSettings()``;
        ``PipelineSettings.paper()`` is the paper's algorithm).
    :param timings_ms: step timings measured before this call (decoding), kept in the result.
    :return: the result; empty with a `warning` when the points cannot be one object in
        metres (:func:`implausible_extent`) or too few points remain.
    """
    settings = settings if settings is not None else PipelineSettings()
    timings = dict(timings_ms or {})
    start = time.perf_counter()
    array = np.asarray(points)
    reason = implausible_extent(array)
    if reason is not None:
        return PipelineResult(counts=_empty_counts(len(array)), timings_ms=timings, warning=reason)
    filtered, counts = filter_points(points, **asdict(settings.filtering))
    timings['filter'] = (time.perf_counter() - start) * 1e3
    min_points = settings.decomposition.min_points
    if len(filtered) < min_points:
        warning = (
            f'only {len(filtered)} of {counts.finite} points left after filtering, fewer than '
            f'min_points = {min_points}'
        )
        return PipelineResult(counts=counts, timings_ms=timings, warning=warning)

    start = time.perf_counter()
    decomposition = decompose(filtered, **asdict(settings.decomposition))
    timings['decompose'] = (time.perf_counter() - start) * 1e3

    start = time.perf_counter()
    grasps = grasp_hypotheses(decomposition, **asdict(settings.grasps))
    timings['grasps'] = (time.perf_counter() - start) * 1e3
    return PipelineResult(
        counts=counts, decomposition=decomposition, grasps=grasps, timings_ms=timings
    )


def decode_cloud(cloud: Any) -> NDArray[np.floating]:
    """
    Decode a PointCloud2 (rclpy or rosbags message) to finite (N, 3) points.

    float32 when the cloud's x, y, z are float32 (no float64 copy of a whole frame: the filter
    takes float32 as it is), float64 otherwise; see :func:`mvbb_ros.pipeline.decode.read_points`.
    """
    return read_points(cloud)


def process_cloud(cloud: Any, settings: PipelineSettings) -> PipelineResult:
    """
    Run the whole pipeline on one `sensor_msgs/PointCloud2` (never modified).

    A malformed cloud gives an empty result whose `warning` says what is wrong.
    """
    start = time.perf_counter()
    try:
        points = decode_cloud(cloud)
    except CloudFormatError as error:
        return PipelineResult(counts=_empty_counts(), warning=f'malformed cloud: {error}')
    timings = {'decode': (time.perf_counter() - start) * 1e3}
    if len(points) == 0:
        return PipelineResult(
            counts=_empty_counts(), timings_ms=timings, warning='cloud has no finite points'
        )
    return process_points(points, settings, timings)
