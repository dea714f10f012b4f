"""`mvbb decompose FILE --json OUT` writes the leaf boxes that the node publishes for the cloud."""

from __future__ import annotations

import json
from pathlib import Path

from builtin_interfaces.msg import Time
from mvbb_ros.cli.main import main
from mvbb_ros.evaluation.synthetic import segmented_object_cloud
from mvbb_ros.pipeline.settings import PRESETS
from mvbb_ros.ros.encode import create_cloud_xyz
from mvbb_ros.ros.messages import MIN_MARKER_SCALE
import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.ros_graph import Graph
from support.shapes import l_shape_points
from visualization_msgs.msg import Marker

pytestmark = pytest.mark.ros


def _published_boxes(parameters: list[Parameter], points: np.ndarray) -> list[np.ndarray]:
    """Publish `points` to a node with `parameters`; return its CUBE scales, by marker id."""
    graph = Graph(parameter_overrides=parameters)
    try:
        cloud = create_cloud_xyz(points, frame_id='camera_optical_frame')
        cloud.header.stamp = Time(sec=7, nanosec=0)
        graph.publish_until_answered(graph.publisher(), cloud)
        assert graph.spin_until(
            lambda: any(b.markers[0].header.stamp.sec == 7 for b in graph.boxes)
        )
        boxes = next(b for b in reversed(graph.boxes) if b.markers[0].header.stamp.sec == 7)
    finally:
        graph.close()
    cubes = [m for m in boxes.markers if m.type == Marker.CUBE and m.action == Marker.ADD]
    return [np.array([m.scale.x, m.scale.y, m.scale.z]) for m in sorted(cubes, key=lambda m: m.id)]


def _written_boxes(path: Path) -> list[np.ndarray]:
    """Return the leaf extents of a `mvbb decompose --json` file, as the node's CUBEs draw them."""
    document = json.loads(path.read_text())
    extents = [leaf['box']['extents'] for leaf in document['leaves']]
    return [np.maximum(np.array(values), MIN_MARKER_SCALE) for values in extents]


def _paper_parameters() -> list[Parameter]:
    """Return the node parameters that turn its defaults into the paper preset."""
    node, paper = PRESETS['node'].parameters(), PRESETS['paper'].parameters()
    return [Parameter(name, value=value) for name, value in paper.items() if value != node[name]]


@pytest.mark.parametrize(
    ('arguments', 'parameters'),
    [([], []), (['--preset', 'paper'], _paper_parameters())],
    ids=['node defaults', 'paper preset'],
)
def test_decompose_writes_the_boxes_the_node_publishes(tmp_path, arguments, parameters):
    points = segmented_object_cloud('mug', seed=0)  # float32, as a depth camera sends them
    cloud_file, out = tmp_path / 'mug.npy', tmp_path / 'mug.json'
    np.save(cloud_file, points)
    assert main(['decompose', str(cloud_file), '--json', str(out), *arguments]) == 0
    written = _written_boxes(out)
    published = _published_boxes(parameters, points)
    assert len(written) == len(published) >= 2, 'several boxes, the same count'
    for mine, theirs in zip(written, published, strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-12)
        assert float(np.prod(mine)) == pytest.approx(float(np.prod(theirs)), rel=1e-12)


def test_decompose_says_why_a_cloud_has_boxes_but_no_grasps(tmp_path, capsys):
    """A 20 cm cube: every face is wider than the gripper opens (0.08 m); the report says so."""
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.1, 0.1, size=(6000, 3))
    axis, side = rng.integers(0, 3, len(points)), rng.choice([-0.1, 0.1], len(points))
    points[np.arange(len(points)), axis] = side
    cloud_file = tmp_path / 'cube.npy'
    np.save(cloud_file, (points + [0.0, 0.0, 0.8]).astype(np.float32))
    assert main(['decompose', str(cloud_file)]) == 0
    report = capsys.readouterr().out
    assert '0 grasp hypotheses' in report
    assert 'no grasps: 1 boxes, 0 grasps: gripper_max_width' in report
    assert main(['decompose', str(cloud_file), '--gripper-max-width', '0.3']) == 0
    assert 'no grasps' not in capsys.readouterr().out


def test_a_cloud_that_is_not_one_view_is_noted_by_the_cli_and_the_node(tmp_path, capsys):
    """
    A cloud all round an object is not one view: the command and the node's diagnostics say so.

    (A model, merged views, or a cloud moved out of its camera's frame without ``viewpoint``:
    the hidden side is not estimated.) A camera's view gets no such note.
    """
    model, view = tmp_path / 'model.npy', tmp_path / 'view.npy'
    np.save(model, l_shape_points().astype(np.float32))
    np.save(view, segmented_object_cloud('mug', seed=0))
    document = tmp_path / 'model.json'
    assert main(['decompose', str(model), '--json', str(document)]) == 0
    report = capsys.readouterr().out
    assert 'note: object 0: shape completion skipped, not one view from [0.0, 0.0, 0.0]' in report
    assert 'is viewpoint the sensor position in the cloud frame?' in report
    skipped = json.loads(document.read_text())['objects'][0]['completion_skipped']
    assert skipped.startswith('not one view from [0.0, 0.0, 0.0]')
    assert main(['decompose', str(view)]) == 0
    assert 'note:' not in capsys.readouterr().out

    graph = Graph()
    try:
        cloud = create_cloud_xyz(np.load(model), frame_id='base_link')
        graph.publish_until_answered(graph.publisher(), cloud)

        def noted() -> bool:
            return any(
                'not one view' in kv.value
                for array in graph.diagnostics
                for status in array.status
                for kv in status.values
                if kv.key == 'completion_skipped'
            )

        assert graph.spin_until(noted, timeout_s=15.0)
    finally:
        graph.close()
