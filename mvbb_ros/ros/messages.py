"""
Build the node's output messages from pipeline results (a thin layer over the geometry).

- boxes: a `visualization_msgs/MarkerArray` that starts with a DELETEALL, then per box a
  translucent CUBE (namespace ``<prefix>boxes``), its twelve edges as a LINE_LIST
  (``<prefix>edges``) and a text label (``<prefix>labels``), with id = box index, so a box keeps
  its namespace and id from one cloud to the next;
- grasps: a `geometry_msgs/PoseArray`, best first;
- grasp_candidates: a `sensor_msgs/PointCloud2` with one point per grasp in the order of
  ``grasps``: float32 fields :data:`GRASP_FLOAT_FIELDS` (position, orientation, the opening the
  gripper needs, the score and the depth) and int32 fields :data:`GRASP_INDEX_FIELDS`;
- tree: the inner (split) boxes of the hierarchy as edges and labels (``tree_`` prefix);
- box_list: a `sensor_msgs/PointCloud2` with one point per box, the leaves first (in the order
  of ``boxes``), then the inner boxes (in the order of ``tree``): :data:`BOX_FLOAT_FIELDS` and
  :data:`BOX_INDEX_FIELDS`;
- support: the support plane's outline (the table the objects stand on) as a
  `geometry_msgs/PolygonStamped`, in the cloud's frame; no points when the cloud has no support
  plane (a segmented object, or ``support_plane: off``). ``~/boxes`` also draws it, namespace
  ``support``: the outline as a LINE_STRIP (id 0) and the plane inside it as a translucent
  TRIANGLE_LIST (id 1), so the table goes with the boxes and their DELETEALL;
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
from geometry_msgs.msg import Point, Point32, PolygonStamped, Pose, PoseArray
from mvbb_ros.geometry.box import Box, box_quaternions, EDGES
from mvbb_ros.geometry.grasping.hypotheses import Grasp
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.scene import SupportPlane
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
from numpy.typing import ArrayLike
from sensor_msgs.msg import PointCloud2
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
#: The outputs of one cloud: topic suffix (below the node's namespace) -> message class, in
#: publication order.
OUTPUT_TYPES: dict[str, type] = {
    'boxes': MarkerArray,
    'tree': MarkerArray,
    'box_list': PointCloud2,
    'grasps': PoseArray,
    'grasp_candidates': PointCloud2,
    'support': PolygonStamped,
}
#: float32 fields of ``~/grasp_candidates`` after x, y, z (the gripper frame's origin):
#: orientation (x, y, z, w), the opening the gripper needs (metres), the score in [0, 1] and
#: how far the gripper moves along its approach before closing (metres).
GRASP_FLOAT_FIELDS = ('qx', 'qy', 'qz', 'qw', 'width', 'score', 'depth')
#: int32 fields of ``~/grasp_candidates``: the leaf box (its index on ``~/boxes`` and
#: ``~/box_list``), the object of the cloud, and the face (+x, -x, +y, -y, +z, -z of the box).
GRASP_INDEX_FIELDS = ('box_index', 'object_index', 'face')
#: float32 fields of ``~/box_list`` after x, y, z (the box centre): orientation (x, y, z, w)
#: and the edge lengths along the box's own x, y and z axes (metres).
BOX_FLOAT_FIELDS = ('qx', 'qy', 'qz', 'qw', 'size_x', 'size_y', 'size_z')
#: int32 fields of ``~/box_list``: points in the box, object index, row of the parent box (-1
#: for a root) and 1 for a leaf, 0 for an inner box.
BOX_INDEX_FIELDS = ('point_count', 'object_index', 'parent', 'leaf')
#: RViz does not draw a CUBE with a zero scale; flat boxes get this thickness (metres).
MIN_MARKER_SCALE = 1e-4
#: The support plane's markers: namespace, outline width (metres) and colour (r, g, b, a).
SUPPORT_NAMESPACE = 'support'
SUPPORT_LINE_WIDTH = 0.005
SUPPORT_COLOR = (0.6, 0.6, 0.6)


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
    objects: Sequence[int] | None = None,
    fill_alpha: float = 0.35,
    line_width: float | None = None,
) -> MarkerArray:
    """
    Draw `boxes` as a MarkerArray: DELETEALL, then per box a CUBE, its edges and a label.

    :param boxes: the boxes, in the header's frame.
    :param header: the input cloud's header (frame and stamp).
    :param namespace_prefix: prefix of the three namespaces (e.g. ``tree_``).
    :param labels: one text per box; None labels boxes by index.
    :param objects: the object index of each box; its markers go to the namespaces
        ``object<k>/boxes``, ``object<k>/edges`` and ``object<k>/labels`` (None: all object 0).
    :param fill_alpha: opacity of the CUBE; 0 draws only edges and labels.
    :param line_width: edge width in metres; None uses 1% of the largest box edge.
    """
    array = MarkerArray()
    array.markers.append(Marker(header=header, action=Marker.DELETEALL))
    if not boxes:
        return array
    largest = max(float(np.max(box.extents)) for box in boxes)
    width = line_width if line_width is not None else max(0.01 * largest, MIN_MARKER_SCALE)
    quaternions = box_quaternions(boxes)
    for index, box in enumerate(boxes):
        prefix = f'object{0 if objects is None else objects[index]}/{namespace_prefix}'
        if fill_alpha > 0.0:
            cube = _marker(header, f'{prefix}boxes', index, Marker.CUBE)
            cube.pose = _pose(box.center, quaternions[index])
            scale = np.maximum(box.extents, MIN_MARKER_SCALE)
            cube.scale.x, cube.scale.y, cube.scale.z = (float(v) for v in scale)
            cube.color = _color(index, fill_alpha)
            array.markers.append(cube)
        edges = _marker(header, f'{prefix}edges', index, Marker.LINE_LIST)
        # Eight Points per box, each listed by the (two or three) edges that meet there: the
        # same serialized message as 24 separate Points, cheaper to construct.
        corners = [Point(x=x, y=y, z=z) for x, y, z in box.corners().tolist()]
        edges.points = [corners[k] for edge in EDGES for k in edge]
        edges.scale.x = width
        edges.color = _color(index, 1.0)
        array.markers.append(edges)
        label = _marker(header, f'{prefix}labels', index, Marker.TEXT_VIEW_FACING)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = (
            float(v) for v in box.center
        )
        label.text = labels[index] if labels is not None else f'box {index}'
        label.scale.z = max(0.15 * largest, 0.01)
        label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        array.markers.append(label)
    return array


def support_polygon(support: SupportPlane | None, header: Header) -> PolygonStamped:
    """Return the support plane's outline as a PolygonStamped (no points without a support)."""
    message = PolygonStamped(header=header)
    if support is not None:
        message.polygon.points = [
            Point32(x=x, y=y, z=z) for x, y, z in support.outline.astype(np.float64).tolist()
        ]
    return message


def support_markers(support: SupportPlane | None, header: Header) -> list[Marker]:
    """Return the support's outline (LINE_STRIP) and plane (TRIANGLE_LIST) markers, or none."""
    if support is None or len(support.outline) < 3:
        return []
    corners = [Point(x=x, y=y, z=z) for x, y, z in support.outline.tolist()]
    red, green, blue = SUPPORT_COLOR
    outline = _marker(header, SUPPORT_NAMESPACE, 0, Marker.LINE_STRIP)
    outline.points = [*corners, corners[0]]
    outline.scale.x = SUPPORT_LINE_WIDTH
    outline.color = ColorRGBA(r=red, g=green, b=blue, a=1.0)
    plane = _marker(header, SUPPORT_NAMESPACE, 1, Marker.TRIANGLE_LIST)
    plane.points = [
        point
        for k in range(1, len(corners) - 1)
        for point in (corners[0], corners[k], corners[k + 1])
    ]
    plane.scale.x = plane.scale.y = plane.scale.z = 1.0
    plane.color = ColorRGBA(r=red, g=green, b=blue, a=0.25)
    return [outline, plane]


def grasp_pose_array(grasps: Sequence[Grasp], header: Header) -> PoseArray:
    """Return the grasp poses, best first, as a PoseArray stamped with `header`."""
    return PoseArray(
        header=header,
        poses=[_pose(grasp.position, grasp.quaternion) for grasp in grasps],
    )


def _table_cloud(
    header: Header,
    xyz: Sequence[ArrayLike],
    floats: Mapping[str, Sequence[float]],
    integers: Mapping[str, Sequence[int]],
) -> PointCloud2:
    """Return a PointCloud2 of rows: float32 x, y, z and `floats`, then int32 `integers`."""
    extra: dict[str, Any] = {
        name: np.asarray(values, dtype=np.float32).reshape(-1) for name, values in floats.items()
    }
    extra.update(
        {name: np.asarray(values, dtype=np.int32).reshape(-1) for name, values in integers.items()}
    )
    points = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    cloud = create_cloud_xyz(points, header=header, fields_extra=extra, dtype=np.float32)
    cloud.is_dense = True
    return cloud


def grasp_candidates_cloud(grasps: Sequence[Grasp], header: Header) -> PointCloud2:
    """
    Return the grasps as a PointCloud2, one point per grasp in the order of the PoseArray.

    Fields: float32 x, y, z (the gripper frame's origin, as the pose), then
    :data:`GRASP_FLOAT_FIELDS`, then int32 :data:`GRASP_INDEX_FIELDS`; packed, no padding.
    """
    quaternions = [grasp.quaternion for grasp in grasps]
    floats: dict[str, Sequence[float]] = {
        name: [float(q[axis]) for q in quaternions]
        for axis, name in enumerate(GRASP_FLOAT_FIELDS[:4])
    }
    floats['width'] = [grasp.width for grasp in grasps]
    floats['score'] = [grasp.score for grasp in grasps]
    floats['depth'] = [grasp.depth for grasp in grasps]
    integers = {
        'box_index': [grasp.box_index for grasp in grasps],
        'object_index': [grasp.object_index for grasp in grasps],
        'face': [grasp.face for grasp in grasps],
    }
    return _table_cloud(header, [grasp.position for grasp in grasps], floats, integers)


def box_list_cloud(result: PipelineResult | None, header: Header) -> PointCloud2:
    """
    Return every box of every object's hierarchy as a PointCloud2: the leaves, then the inner.

    Row ``i < len(leaves)`` is leaf ``i`` (``box_index`` of the grasps, marker id on
    ``~/boxes``); the inner (split) boxes follow in the order of ``~/tree``. Fields: float32
    x, y, z (the centre) and :data:`BOX_FLOAT_FIELDS`, int32 :data:`BOX_INDEX_FIELDS`;
    ``point_count`` counts the points the sensor saw in the box (not the estimated hidden side),
    ``parent`` is the row of the box it was split from (-1 for an object's root).
    """
    objects = [] if result is None else result.objects
    leaves = [(item, node) for item in objects for node in item.decomposition.leaf_nodes]
    inner = [
        (item, node) for item in objects for node in item.decomposition.nodes if node.children
    ]
    rows = [*leaves, *inner]
    row_of = {(item.index, node.index): row for row, (item, node) in enumerate(rows)}
    quaternions = box_quaternions([node.box for _, node in rows])
    floats: dict[str, Sequence[float]] = {
        name: [float(q[axis]) for q in quaternions]
        for axis, name in enumerate(BOX_FLOAT_FIELDS[:4])
    }
    floats.update(
        {
            name: [float(node.box.extents[axis]) for _, node in rows]
            for axis, name in enumerate(BOX_FLOAT_FIELDS[4:])
        }
    )
    integers = {
        'point_count': [
            int(np.count_nonzero(node.point_indices < item.shape.observed)) for item, node in rows
        ],
        'object_index': [item.index for item, _ in rows],
        'parent': [
            -1 if node.parent is None else row_of.get((item.index, node.parent), -1)
            for item, node in rows
        ],
        'leaf': [1] * len(leaves) + [0] * len(inner),
    }
    return _table_cloud(header, [node.box.center for _, node in rows], floats, integers)


def diagnostic_status(
    name: str,
    level: bytes,
    message: str,
    values: Mapping[str, object],
    hardware_id: str = '',
) -> DiagnosticStatus:
    """Return a DiagnosticStatus with `values` as key/value strings."""
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
    )


def output_messages(
    result: PipelineResult | None, header: Header, settings: PipelineSettings
) -> dict[str, Any]:
    """
    Return the output messages of one cloud, by topic suffix (see :data:`OUTPUT_TYPES`).

    The node publishes them on ``~/<suffix>`` and `mvbb bag process` writes them, so what a bag
    gives offline is what the node publishes live. Without a decomposition (`result` None after
    a failure, or a result with a warning) the messages are cleared: a lone DELETEALL, an
    empty PoseArray and PointCloud2s without points.

    :param result: the pipeline result, or None when processing failed.
    :param header: the input cloud's header; every message is stamped with it.
    :param settings: the settings in force (``publish_tree`` adds the ``tree`` message).
    :return: ``boxes``, ``box_list``, ``grasps``, ``grasp_candidates`` and ``support``, and
        ``tree`` when ``settings.node.publish_tree``, in publication order.
    """
    leaves = [] if result is None else result.leaves
    objects = [] if result is None else result.leaf_object_indices
    counts = [] if result is None else result.leaf_observed_counts
    cut = set() if result is None else set(result.cut_objects)
    labels = [
        (f'{index}: {count} pts' if len(set(objects)) < 2 else f'{obj}.{index}: {count} pts')
        + (', cut by the view' if obj in cut else '')
        for index, (obj, count) in enumerate(zip(objects, counts, strict=True))
    ]
    support = None if result is None else result.support
    boxes = box_markers(leaves, header, labels=labels, objects=objects)
    boxes.markers.extend(support_markers(support, header))
    outputs: dict[str, Any] = {'boxes': boxes}
    if settings.node.publish_tree:
        inner = [] if result is None else result.inner_boxes
        inner_objects = [] if result is None else result.inner_object_indices
        outputs['tree'] = box_markers(
            inner, header, namespace_prefix='tree_', fill_alpha=0.0, objects=inner_objects
        )
    outputs['box_list'] = box_list_cloud(result, header)
    grasps = [] if result is None else result.grasps
    outputs['grasps'] = grasp_pose_array(grasps, header)
    outputs['grasp_candidates'] = grasp_candidates_cloud(grasps, header)
    outputs['support'] = support_polygon(support, header)
    return outputs


def cleared_tree(header: Header) -> MarkerArray:
    """Return the ``~/tree`` message that removes the drawn hierarchy (a lone DELETEALL)."""
    return box_markers([], header)
