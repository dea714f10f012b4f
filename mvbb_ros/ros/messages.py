"""
Build the node's output messages from pipeline results (a thin layer over the geometry).

- boxes: a `visualization_msgs/MarkerArray` that starts with a DELETEALL, then per box a
  translucent CUBE (namespace ``<prefix>boxes``), its twelve edges as a LINE_LIST
  (``<prefix>edges``) and a text label (``<prefix>labels``), with id = box index, so a box keeps
  its namespace and id from one cloud to the next;
- grasps: a `geometry_msgs/PoseArray`, best first;
- tree: the inner (non-leaf) boxes of the hierarchy as edges and labels (``tree_`` prefix);
- diagnostics: a `diagnostic_msgs/DiagnosticStatus` with counts and timings.

All are stamped with the input cloud's header; nothing else is assumed about frames.
:func:`output_messages` turns one pipeline result into the messages of one cloud; the node
publishes them and `mvbb bag process` writes them, so both produce the same messages.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray
from mvbb_ros.geometry.box import Box, EDGES
from mvbb_ros.geometry.grasps import Grasp
from mvbb_ros.pipeline.process import PipelineResult
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

#: Distinct box colours (red, green, blue in 0..1), cycled by box index.
PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.12, 0.47, 0.71),
    (1.00, 0.50, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.40, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.50, 0.50, 0.50),
    (0.74, 0.74, 0.13),
    (0.09, 0.75, 0.81),
)
#: The outputs of one cloud: topic suffix (below the node's namespace) -> message class.
OUTPUT_TYPES: dict[str, type] = {'boxes': MarkerArray, 'tree': MarkerArray, 'grasps': PoseArray}
#: RViz does not draw a CUBE with a zero scale; flat boxes get this thickness (metres).
MIN_MARKER_SCALE = 1e-4


def _color(index: int, alpha: float) -> ColorRGBA:
    red, green, blue = PALETTE[index % len(PALETTE)]
    return ColorRGBA(r=red, g=green, b=blue, a=alpha)


def _pose(position: Iterable[float], quaternion: Iterable[float]) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    (
        pose.orientation.x,
        pose.orientation.y,
        pose.orientation.z,
        pose.orientation.w,
    ) = (float(v) for v in quaternion)
    return pose


def _marker(header: Header, namespace: str, marker_id: int, marker_type: int) -> Marker:
    marker = Marker(header=header, ns=namespace, id=marker_id, type=marker_type)
    marker.action = Marker.ADD
    marker.lifetime = Duration(sec=0, nanosec=0)
    marker.pose.orientation.w = 1.0
    return marker


def box_markers(
    boxes: Sequence[Box],
    header: Header,
    *,
    namespace_prefix: str = '',
    labels: Sequence[str] | None = None,
    fill_alpha: float = 0.35,
    line_width: float | None = None,
) -> MarkerArray:
    """
    Draw `boxes` as a MarkerArray: DELETEALL, then per box a CUBE, its edges and a label.

    :param boxes: the boxes, in the header's frame.
    :param header: the input cloud's header (frame and stamp).
    :param namespace_prefix: prefix of the three namespaces (e.g. ``tree_``).
    :param labels: one text per box; None labels boxes by index.
    :param fill_alpha: opacity of the CUBE; 0 draws only edges and labels.
    :param line_width: edge width in metres; None uses 1% of the largest box edge.
    """
    array = MarkerArray()
    array.markers.append(Marker(header=header, action=Marker.DELETEALL))
    if not boxes:
        return array
    largest = max(float(np.max(box.extents)) for box in boxes)
    width = line_width if line_width is not None else max(0.01 * largest, MIN_MARKER_SCALE)
    for index, box in enumerate(boxes):
        if fill_alpha > 0.0:
            cube = _marker(header, f'{namespace_prefix}boxes', index, Marker.CUBE)
            cube.pose = _pose(box.center, box.quaternion)
            scale = np.maximum(box.extents, MIN_MARKER_SCALE)
            cube.scale.x, cube.scale.y, cube.scale.z = (float(v) for v in scale)
            cube.color = _color(index, fill_alpha)
            array.markers.append(cube)
        edges = _marker(header, f'{namespace_prefix}edges', index, Marker.LINE_LIST)
        # Eight Points per box, each listed by the (two or three) edges that meet there: the
        # same serialized message as 24 separate Points, for a third of the construction cost.
        corners = [Point(x=x, y=y, z=z) for x, y, z in box.corners().tolist()]
        edges.points = [corners[k] for edge in EDGES for k in edge]
        edges.scale.x = width
        edges.color = _color(index, 1.0)
        array.markers.append(edges)
        label = _marker(header, f'{namespace_prefix}labels', index, Marker.TEXT_VIEW_FACING)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = (
            float(v) for v in box.center
        )
        label.text = labels[index] if labels is not None else f'box {index}'
        label.scale.z = max(0.15 * largest, 0.01)
        label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        array.markers.append(label)
    return array


def grasp_pose_array(grasps: Sequence[Grasp], header: Header) -> PoseArray:
    """Return the grasp poses, best first, as a PoseArray stamped with `header`."""
    return PoseArray(
        header=header,
        poses=[_pose(grasp.position, grasp.quaternion) for grasp in grasps],
    )


def diagnostic_status(
    name: str, level: bytes, message: str, values: Mapping[str, object]
) -> DiagnosticStatus:
    """Return a DiagnosticStatus with `values` as key/value strings."""
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id='',
        values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
    )


def output_messages(
    result: PipelineResult | None, header: Header, settings: PipelineSettings
) -> dict[str, Any]:
    """
    Return the output messages of one cloud, by topic suffix (see :data:`OUTPUT_TYPES`).

    The node publishes them on ``~/<suffix>`` and `mvbb bag process` writes them, so what a bag
    gives offline is what the node publishes live. Without a decomposition (`result` None after
    a failure, or a result with a warning) the messages are cleared: a lone DELETEALL and an
    empty PoseArray.

    :param result: the pipeline result, or None when processing failed.
    :param header: the input cloud's header; every message is stamped with it.
    :param settings: the settings in force (``publish_tree`` adds the ``tree`` message).
    :return: ``boxes`` and ``grasps``, and ``tree`` when ``settings.node.publish_tree``, in
        publication order.
    """
    decomposition = None if result is None else result.decomposition
    leaves = [] if decomposition is None else list(decomposition.leaves)
    counts = [] if decomposition is None else decomposition.leaf_point_indices
    labels = [f'{i}: {len(indices)} pts' for i, indices in enumerate(counts)]
    outputs: dict[str, Any] = {'boxes': box_markers(leaves, header, labels=labels)}
    if settings.node.publish_tree:
        inner = (
            []
            if decomposition is None
            else [node.box for node in decomposition.nodes if not node.is_leaf]
        )
        outputs['tree'] = box_markers(inner, header, namespace_prefix='tree_', fill_alpha=0.0)
    grasps = [] if result is None else result.grasps
    outputs['grasps'] = grasp_pose_array(grasps, header)
    return outputs
