"""Pictures of clouds, boxes and grasps: files, sizes, content, atomic writes and errors."""

from __future__ import annotations

from dataclasses import dataclass
import os

from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.figure import Figure
import matplotlib.image as mpimg
from mvbb_ros.cli import render
from mvbb_ros.cli.render import BEST_GRASP_COLOR, BOX_COLORS, Panel, render_boxes, render_panels
from mvbb_ros.geometry.box import Box
import numpy as np
import pytest


@dataclass
class FakeGrasp:
    position: np.ndarray
    approach: np.ndarray
    closing: np.ndarray
    width: float


def two_blocks(seed=0):
    """Return an L-shaped cloud (metres) of two blocks, and a box around each block."""
    rng = np.random.default_rng(seed)
    base = rng.uniform([-0.10, -0.03, 0.0], [0.10, 0.03, 0.04], size=(3000, 3))
    tower = rng.uniform([0.04, -0.03, 0.04], [0.10, 0.03, 0.16], size=(2000, 3))
    points = np.concatenate([base, tower])
    return points, [Box.enclosing(base), Box.enclosing(tower)]


def grasps_on(box):
    top = box.center + np.array([0.0, 0.0, box.extents[2] / 2.0 + 0.05])
    side = box.center + np.array([box.extents[0] / 2.0 + 0.05, 0.0, 0.0])
    return [
        FakeGrasp(top, np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), box.extents[0]),
        FakeGrasp(side, np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), box.extents[1]),
    ]


def read_rgb(path):
    image = mpimg.imread(path)
    assert image.dtype == np.float32  # PNGs decode to floats in [0, 1]
    return image[..., :3]


def color_pixels(image, hex_color, tol=0.08):
    rgb = np.array([int(hex_color[i], 16) * 16 + int(hex_color[i + 1], 16) for i in (1, 3, 5)])
    rgb = rgb / 255.0
    return int(np.count_nonzero(np.all(np.abs(image - rgb) < tol, axis=-1)))


def test_render_boxes_writes_a_png_of_the_expected_size_with_boxes_and_grasps(tmp_path):
    points, boxes = two_blocks()
    path = tmp_path / 'boxes.png'
    written = render_boxes(path, points, boxes, grasps=grasps_on(boxes[1]), title='two blocks')
    assert written == path
    assert path.stat().st_size > 10_000
    image = read_rgb(path)
    # Three 3-inch views plus the legend column, one row plus its header, at 110 dpi.
    width_in = 3 * 3.0 + render._LEGEND_WIDTH
    height_in = 3.0 + render._ROW_HEADER
    assert image.shape[1] == pytest.approx(width_in * 110, abs=1)
    assert image.shape[0] == pytest.approx(height_in * 110, abs=1)
    assert image.std() > 0.05  # not blank
    assert color_pixels(image, BOX_COLORS[0]) > 200
    assert color_pixels(image, BOX_COLORS[1]) > 200
    assert color_pixels(image, BEST_GRASP_COLOR) > 50
    assert sorted(os.listdir(tmp_path)) == ['boxes.png']  # no temporary files left


def test_without_grasps_there_is_no_grasp_colour(tmp_path):
    points, boxes = two_blocks()
    render_boxes(tmp_path / 'plain.png', points, boxes)
    image = read_rgb(tmp_path / 'plain.png')
    assert color_pixels(image, BEST_GRASP_COLOR, tol=0.05) == 0
    assert color_pixels(image, BOX_COLORS[0]) > 200


def test_rendering_is_deterministic(tmp_path):
    points, boxes = two_blocks()
    cloud = np.concatenate([points, np.random.default_rng(1).normal(size=(40_000, 3)) * 0.05])
    render_boxes(tmp_path / 'a.png', cloud, boxes, max_points=5000)
    render_boxes(tmp_path / 'b.png', cloud, boxes, max_points=5000)
    assert np.array_equal(read_rgb(tmp_path / 'a.png'), read_rgb(tmp_path / 'b.png'))


def test_panels_stack_one_row_per_decomposition(tmp_path):
    points, boxes = two_blocks()
    panels = [
        Panel(points, [Box.enclosing(points)], title='t = 0.90: 1 box'),
        Panel(points, boxes, title='t = 0.94: 2 boxes'),
        Panel(points, boxes, grasps=grasps_on(boxes[0]), title='t = 0.98: 2 boxes'),
    ]
    path = render_panels(tmp_path / 'panels.png', panels, views=('top', 'iso'), title='blocks')
    image = read_rgb(path)
    height_in = 3 * (3.0 + render._ROW_HEADER) + 0.45
    assert image.shape[0] == pytest.approx(height_in * 110, abs=1)
    assert image.shape[1] == pytest.approx((2 * 3.0 + render._LEGEND_WIDTH) * 110, abs=1)
    # Each row draws its boxes: the second colour only appears in rows 2 and 3.
    header = int(0.45 * 110)  # the figure title
    rows = np.array_split(image[header:], 3)
    assert color_pixels(rows[0], BOX_COLORS[1]) == 0
    assert color_pixels(rows[1], BOX_COLORS[1]) > 100
    assert color_pixels(rows[2], BEST_GRASP_COLOR) > 20


def test_other_formats_follow_the_extension(tmp_path):
    points, boxes = two_blocks()
    svg = render_boxes(tmp_path / 'boxes.svg', points, boxes, max_points=500)
    assert svg.read_text().lstrip().startswith('<?xml')
    pdf = render_boxes(tmp_path / 'boxes.pdf', points, boxes, max_points=500)
    assert pdf.read_bytes().startswith(b'%PDF')


def test_failed_drawing_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / 'picture.png'
    path.write_bytes(b'old picture')
    real_savefig = Figure.savefig

    def broken_savefig(self, fname, **kwargs):
        real_savefig(self, fname, **kwargs)  # a complete file in the temporary place ...
        raise RuntimeError('disk full')  # ... then a failure

    monkeypatch.setattr(Figure, 'savefig', broken_savefig)
    points, boxes = two_blocks()
    with pytest.raises(RuntimeError, match='disk full'):
        render_boxes(path, points, boxes)
    assert path.read_bytes() == b'old picture'
    assert sorted(os.listdir(tmp_path)) == ['picture.png']


def test_replacing_a_picture_is_atomic(tmp_path):
    path = tmp_path / 'picture.png'
    path.write_bytes(b'old picture')
    points, boxes = two_blocks()
    render_boxes(path, points, boxes, max_points=1000)
    assert path.read_bytes().startswith(b'\x89PNG')
    assert sorted(os.listdir(tmp_path)) == ['picture.png']


@pytest.mark.parametrize(
    ('call', 'message'),
    [
        (lambda p: render_boxes(p, np.zeros((4, 2)), []), 'shape'),
        (lambda p: render_boxes(p, np.zeros((4, 3)), [], views=('under',)), 'unknown view'),
        (lambda p: render_boxes(p, np.zeros((4, 3)), [], views=()), 'at least one view'),
        (lambda p: render_boxes(p, np.zeros((4, 3)), [], frame='mine'), 'frame'),
        (lambda p: render_panels(p, []), 'at least one panel'),
        (lambda p: render_boxes(p.with_suffix('.xyz'), np.zeros((4, 3)), []), 'format'),
    ],
)
def test_bad_arguments_are_refused_and_write_nothing(tmp_path, call, message):
    with pytest.raises(ValueError, match=message):
        call(tmp_path / 'out.png')
    assert os.listdir(tmp_path) == []


def test_odd_inputs_still_give_a_picture(tmp_path):
    points, boxes = two_blocks()
    organized = np.full((40, 50, 3), np.nan)
    organized[10:30, 10:40] = np.random.default_rng(0).random((20, 30, 3)) * 0.1
    cases = {
        'boxes_only': (np.zeros((0, 3)), boxes),
        'points_only': (points, []),
        'one_point': (np.array([[0.1, 0.2, 0.3]]), [Box.enclosing([[0.1, 0.2, 0.3]])]),
        'flat': (points * [1.0, 1.0, 0.0], [Box.enclosing(points * [1.0, 1.0, 0.0])]),
        'organized_nan': (organized, [Box.enclosing(organized[10:30, 10:40].reshape(-1, 3))]),
        'millimetres': (points * 1000.0, [Box.enclosing(points * 1000.0)]),
    }
    for name, (cloud, cloud_boxes) in cases.items():
        path = render_boxes(
            tmp_path / f'{name}.png', cloud, cloud_boxes, unit='mm', title=name, views=('iso',)
        )
        assert read_rgb(path).std() > 0.02, name


def test_views_in_the_data_frame_and_from_any_angle(tmp_path):
    points, boxes = two_blocks()
    rotation = Box.enclosing(points).rotation
    for frame in ('data', rotation):
        path = render_boxes(
            tmp_path / 'views.png', points, boxes, views=('camera', (10.0, 30.0)), frame=frame
        )
        assert read_rgb(path).std() > 0.05


def test_hidden_edges_are_those_behind_the_box():
    box = Box(center=np.zeros(3), rotation=np.eye(3), extents=[1.0, 2.0, 3.0])
    corners = box.corners()
    from_above = render._hidden_edges(box, np.array([0.0, 0.0, 1.0]))
    visible = [edge for edge, hidden in zip(render.EDGES, from_above, strict=True) if not hidden]
    # Straight from above only the top face's four edges are in front.
    assert len(visible) == 4
    assert all(corners[i, 2] > 0 and corners[j, 2] > 0 for i, j in visible)
    oblique = render._hidden_edges(box, np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0))
    hidden = [edge for edge, is_hidden in zip(render.EDGES, oblique, strict=True) if is_hidden]
    # From a corner direction the three edges at the far corner are hidden.
    assert len(hidden) == 3
    assert all(0 in edge for edge in hidden)  # corner 0 is (-, -, -)


def test_scale_bar_lengths_are_round_numbers():
    assert render._nice_length(1.0) == pytest.approx(0.2)
    assert render._nice_length(0.26) == pytest.approx(0.1)
    assert render._nice_length(0.049) == pytest.approx(0.01)
    assert render._format_length(0.05, 'm') == '5 cm'
    assert render._format_length(0.002, 'm') == '2 mm'
    assert render._format_length(20.0, 'mm') == '20 mm'


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
        lambda v: np.linalg.norm(v) > 0.1
    ),
    st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
    st.integers(0, 2**16),
)
def test_the_ground_frame_stands_on_up_and_faces_away_from_the_sensor(up, eye, seed):
    """Columns right, forward, up: orthonormal, right-handed, forward level and away from eye."""
    points = np.random.default_rng(seed).normal(0.0, 0.3, (50, 3))
    frame = render.ground_frame(up, eye, points)
    unit_up = np.asarray(up) / np.linalg.norm(up)
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-9)
    assert np.linalg.det(frame) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(frame[:, 2], unit_up, atol=1e-12)
    sight = points.mean(axis=0) - np.asarray(eye)
    level = sight - (sight @ unit_up) * unit_up
    if np.linalg.norm(level) > 1e-6:
        assert frame[:, 1] @ level == pytest.approx(np.linalg.norm(level), rel=1e-6)


def test_a_sensor_looking_straight_down_still_gets_a_ground_frame():
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    frame = render.ground_frame((0.0, 0.0, 1.0), (0.0, 0.0, 1.5), points)
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(frame[:, 2], [0.0, 0.0, 1.0])
