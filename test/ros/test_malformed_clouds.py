"""
A corpus of malformed and degenerate clouds through the running node (issue 8).

For each cloud the node keeps running, either processes it or says clearly why not (the text it
logs, throttled, is the result's warning), publishes a consistent result or a cleared one, and
leaves the input message's bytes unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from builtin_interfaces.msg import Time
from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField
from support.ros_graph import Graph
from support.shapes import l_shape_points
from visualization_msgs.msg import Marker

pytestmark = pytest.mark.ros

RNG_SEED = 8


@pytest.fixture(scope='module')
def graph():
    # The corpus is about decoding: its clouds are not all in metres near the sensor (int16
    # millimetres, a 100 m object), so the region of interest is off.
    graph = Graph([Parameter('roi_max_distance', value=0.0)])
    yield graph
    graph.close()


def _fields(*specs: tuple[str, int, int]) -> list[PointField]:
    return [
        PointField(name=name, offset=offset, datatype=kind, count=1)
        for name, offset, kind in specs
    ]


def _xyz_fields(kind: int = PointField.FLOAT32, size: int = 4) -> list[PointField]:
    return _fields(('x', 0, kind), ('y', size, kind), ('z', 2 * size, kind))


def _raw_cloud(
    fields: list[PointField],
    data: bytes,
    width: int,
    height: int = 1,
    point_step: int = 12,
    row_step: int | None = None,
    is_bigendian: bool = False,
    is_dense: bool = True,
) -> PointCloud2:
    cloud = PointCloud2()
    cloud.fields = fields
    cloud.width, cloud.height = width, height
    cloud.point_step = point_step
    cloud.row_step = width * point_step if row_step is None else row_step
    cloud.is_bigendian, cloud.is_dense = is_bigendian, is_dense
    cloud.data = data
    return cloud


def _object(count: int = 3000) -> np.ndarray:
    return l_shape_points(seed=RNG_SEED, count=count)


def _typed(points: np.ndarray, dtype: str, kind: int) -> PointCloud2:
    values = np.ascontiguousarray(points.astype(dtype))
    size = np.dtype(dtype).itemsize
    return _raw_cloud(_xyz_fields(kind, size), values.tobytes(), len(points), point_step=3 * size)


def _with_fields(points: np.ndarray, fields: list[PointField], point_step: int) -> PointCloud2:
    return _raw_cloud(
        fields,
        np.ascontiguousarray(points, dtype='<f4').tobytes(),
        len(points),
        point_step=point_step,
    )


def _organized_with_holes() -> PointCloud2:
    rng = np.random.default_rng(RNG_SEED)
    grid = np.full((480, 640, 3), np.nan, dtype=np.float32)
    inside = _object(480 * 640)
    grid.reshape(-1, 3)[: len(inside)] = inside[: 480 * 640]
    holes = rng.random((480, 640)) < 0.3
    grid[holes] = np.nan
    return create_cloud_xyz(grid.reshape(-1, 3), organized_shape=(480, 640))


def _is_dense_lie() -> PointCloud2:
    points = _object().astype(np.float32)
    points[::7] = np.nan
    cloud = create_cloud_xyz(points)
    cloud.is_dense = True
    return cloud


def _some_inf() -> PointCloud2:
    points = _object()
    points[::11, 1] = np.inf
    points[::13, 2] = -np.inf
    return create_cloud_xyz(points)


def _random_bytes() -> PointCloud2:
    rng = np.random.default_rng(RNG_SEED)
    return _raw_cloud(_xyz_fields(), rng.bytes(12 * 997 - 5), 997)


def _random_float_bytes(count: int = 997) -> PointCloud2:
    """Return a well-formed cloud of random bytes: float32 coordinates up to 3.4e38, NaNs."""
    rng = np.random.default_rng(RNG_SEED)
    return _raw_cloud(_xyz_fields(), rng.bytes(12 * count), count)


def _big_endian() -> PointCloud2:
    points = _object()
    return _raw_cloud(
        _xyz_fields(), points.astype('>f4').tobytes(), len(points), is_bigendian=True
    )


@dataclass(frozen=True)
class Case:
    """A corpus entry: how to build the cloud and whether the node should use it."""

    build: Callable[[], PointCloud2]
    processed: bool
    reason: str = ''


def _line(count: int = 500) -> np.ndarray:
    return np.outer(np.linspace(0.0, 0.3, count), [1.0, 0.5, 0.2]) + [0.0, 0.0, 0.8]


def _plane(count: int = 2000) -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    flat = rng.uniform(-0.1, 0.1, size=(count, 3))
    flat[:, 2] = 0.7
    return flat


CORPUS: dict[str, Case] = {
    'empty': Case(lambda: create_cloud_xyz(np.zeros((0, 3))), False, 'no finite points'),
    'zero width': Case(lambda: _raw_cloud(_xyz_fields(), b'', 0, height=5), False, 'no finite'),
    'zero height': Case(lambda: _raw_cloud(_xyz_fields(), b'', 10, height=0), False, 'no finite'),
    'data too short': Case(
        lambda: _raw_cloud(_xyz_fields(), bytes(12 * 99), 100), False, 'malformed'
    ),
    'data longer than needed': Case(
        lambda: _raw_cloud(
            _xyz_fields(), _object().astype('<f4').tobytes() + bytes(17), len(_object())
        ),
        True,
    ),
    'row_step too small': Case(
        lambda: _raw_cloud(_xyz_fields(), bytes(12 * 100), 100, row_step=600), False, 'row_step'
    ),
    'point_step smaller than fields': Case(
        lambda: _raw_cloud(_xyz_fields(), bytes(8 * 100), 100, point_step=8), False, 'malformed'
    ),
    'missing x': Case(
        lambda: _with_fields(_object(), _fields(('y', 4, 7), ('z', 8, 7)), 12), False, "'x'"
    ),
    'missing y': Case(
        lambda: _with_fields(_object(), _fields(('x', 0, 7), ('z', 8, 7)), 12), False, "'y'"
    ),
    'missing z': Case(
        lambda: _with_fields(_object(), _fields(('x', 0, 7), ('y', 4, 7)), 12), False, "'z'"
    ),
    'xyz as int16': Case(lambda: _typed(_object() * 1000, '<i2', PointField.INT16), True),
    'xyz as uint8': Case(lambda: _typed(_object() * 400, '<u1', PointField.UINT8), True),
    'xyz as float64': Case(lambda: _typed(_object(), '<f8', PointField.FLOAT64), True),
    'big-endian': Case(_big_endian, True),
    'duplicated field names': Case(
        lambda: _with_fields(
            _object(), _fields(('x', 0, 7), ('y', 4, 7), ('z', 8, 7), ('x', 8, 7)), 12
        ),
        False,
        'malformed',
    ),
    'field offset beyond point_step': Case(
        lambda: _with_fields(_object(), _fields(('x', 0, 7), ('y', 4, 7), ('z', 10, 7)), 12),
        False,
        'malformed',
    ),
    'unknown x datatype': Case(
        lambda: _with_fields(_object(), _fields(('x', 0, 42), ('y', 4, 7), ('z', 8, 7)), 12),
        False,
        'malformed',
    ),
    'all NaN': Case(lambda: create_cloud_xyz(np.full((500, 3), np.nan)), False, 'no finite'),
    'some inf': Case(_some_inf, True),
    'is_dense true with NaNs': Case(_is_dense_lie, True),
    'organized 640x480 with holes': Case(_organized_with_holes, True),
    '1 point': Case(lambda: create_cloud_xyz(_object()[:1]), False, 'min_points'),
    '2 points': Case(lambda: create_cloud_xyz(_object()[:2]), False, 'min_points'),
    '3 points': Case(lambda: create_cloud_xyz(_object()[:3]), False, 'min_points'),
    'collinear': Case(lambda: create_cloud_xyz(_line()), True),
    'coplanar': Case(lambda: create_cloud_xyz(_plane()), True),
    'all identical': Case(
        lambda: create_cloud_xyz(np.tile([[0.1, 0.2, 0.9]], (1000, 1))), False, 'min_points'
    ),
    'coordinates at 1e6 m': Case(
        lambda: create_cloud_xyz(_object() + 1e6, dtype=np.float64), True
    ),
    '1 mm object': Case(
        lambda: create_cloud_xyz(_object() * 0.005 + [0, 0, 0.5]), False, 'min_points'
    ),
    '100 m object': Case(lambda: create_cloud_xyz(_object() * 500.0), True),
    '2 million points': Case(lambda: create_cloud_xyz(_object(2_000_000)), True),
    'random bytes': Case(_random_bytes, False, 'malformed'),
    'random bytes, well formed': Case(_random_float_bytes, False, 'absurd cloud'),
    '2 km wide': Case(lambda: create_cloud_xyz(_object() * 1e4), False, 'more than 1000 m'),
}


@pytest.mark.parametrize('name', list(CORPUS))
def test_corpus_cloud(graph, name):
    case = CORPUS[name]
    cloud = case.build()
    cloud.header.frame_id = 'corpus'
    cloud.header.stamp = Time(sec=1000 + list(CORPUS).index(name), nanosec=0)
    data_before = bytes(cloud.data)
    layout_before = (cloud.width, cloud.height, cloud.point_step, cloud.row_step)

    grasps = graph.publish_until_answered(graph.publisher(), cloud)
    assert graph.spin_until(
        lambda: (
            graph.boxes and graph.boxes[-1].markers[0].header.stamp.sec == cloud.header.stamp.sec
        )
    )
    boxes = graph.boxes[-1]
    result = graph.node._last_result

    assert bytes(cloud.data) == data_before, 'the input message must never be modified'
    assert (cloud.width, cloud.height, cloud.point_step, cloud.row_step) == layout_before
    assert grasps.header.stamp.sec == cloud.header.stamp.sec
    assert boxes.markers[0].action == Marker.DELETEALL
    cubes = [m for m in boxes.markers if m.type == Marker.CUBE]
    edges = [m for m in boxes.markers if m.type == Marker.LINE_LIST]
    if case.processed:
        assert result is not None and result.warning is None, result and result.warning
        assert len(cubes) == len(edges) == len(result.leaves) >= 1
        for cube in cubes:
            scale = [cube.scale.x, cube.scale.y, cube.scale.z]
            assert all(np.isfinite(scale)) and min(scale) > 0.0
    else:
        assert len(boxes.markers) == 1, 'a rejected cloud clears the boxes'
        assert len(grasps.poses) == 0
        assert result is not None and result.warning is not None
        assert case.reason.lower() in result.warning.lower()


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 30


def test_node_processes_a_good_cloud_after_the_corpus(graph):
    grasps = graph.publish_until_answered(graph.publisher(), create_cloud_xyz(_object()))
    assert len(grasps.poses) > 0
    assert graph.node._stats['clouds_failed'] == 0, 'no cloud of the corpus crashed the pipeline'


def test_absurd_clouds_give_one_warning_and_no_traceback(capfd):
    graph = Graph()  # its own node: nothing logged before
    try:
        publisher = graph.publisher()
        for sec in (1, 2, 3):
            cloud = _random_float_bytes()
            cloud.header.stamp = Time(sec=sec, nanosec=0)
            grasps = graph.publish_until_answered(publisher, cloud)
            assert len(grasps.poses) == 0
        assert graph.node._stats['clouds_rejected'] >= 3
        assert graph.node._stats['clouds_failed'] == 0
        assert [m.action for m in graph.boxes[-1].markers] == [Marker.DELETEALL]
        logged = capfd.readouterr().err
        assert logged.count('absurd cloud') == 1, logged
        assert 'span' in logged and 'Traceback' not in logged
    finally:
        graph.close()
