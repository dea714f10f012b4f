"""Tests for face-approach grasp hypotheses (mvbb_ros.geometry.grasping.hypotheses)."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros import Grasp, grasp_hypotheses
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition.result import (
    Decomposition,
    DecompositionNode,
    DecompositionSettings,
)
import mvbb_ros.geometry.grasping.hypotheses as grasp_module
from mvbb_ros.geometry.grasping.hypotheses import grasp_filter_counts
import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial.transform import Rotation

FACE_NAMES = grasp_module.FACE_NAMES
HYPOTHESES_PER_BOX = grasp_module.HYPOTHESES_PER_BOX
boxes_intersect = grasp_module.boxes_intersect
WIDE = 10.0  # a gripper that spans every box in these tests (metres)
AXIS_INDEX = {'x': 0, 'z': 2}


def axis_box(low: list[float], high: list[float]) -> Box:
    low_array, high_array = np.asarray(low, float), np.asarray(high, float)
    return Box(center=(low_array + high_array) / 2, rotation=np.eye(3), extents=high_array - low)


def face_set(grasps: list[Grasp]) -> set[tuple[int, str]]:
    return {(grasp.box_index, grasp.face_name) for grasp in grasps}


def all_faces(count: int) -> set[tuple[int, str]]:
    return {(box, name) for box in range(count) for name in FACE_NAMES}


def decomposition_of(
    leaves: list[Box], points: np.ndarray, kept_point_indices: list[int] | None = None
) -> Decomposition:
    """
    Return a Decomposition with the given leaf boxes over `points` (a hand-made tree).

    The root holds every point; the first leaf holds the kept points (all of them unless
    `kept_point_indices` says which), the other leaves none, and a dropped child the rest.
    """
    points = np.asarray(points, dtype=np.float64)
    everything = np.arange(len(points))
    kept = everything if kept_point_indices is None else np.asarray(kept_point_indices)
    parts = [(box, kept if index == 0 else np.empty(0, dtype=np.intp), False)
             for index, box in enumerate(leaves)]  # fmt: skip
    dropped = np.setdiff1d(everything, kept)
    if len(dropped):
        parts.append((leaves[0], dropped, True))

    def node(index, box, indices, parent, children=(), dropped=False):
        return DecompositionNode(
            index=index, box=box, point_indices=np.asarray(indices, dtype=np.intp),
            parent=parent, children=children, cut=None, tested_cut=None, theta=None, gain=None,
            depth=0 if parent is None else 1, dropped=dropped,
            stop_reason=None if children else ('dropped' if dropped else 'gain'),
        )  # fmt: skip

    children = tuple(range(1, len(parts) + 1))
    nodes = [node(0, leaves[0], everything, None, children)]
    nodes += [node(i, box, part, 0, dropped=gone) for i, (box, part, gone) in enumerate(parts, 1)]
    return Decomposition(points=points, nodes=tuple(nodes), settings=DecompositionSettings())


# Hypothesis strategies ---------------------------------------------------------------------------

rotations = st.integers(0, 2**32 - 1).map(
    lambda seed: Rotation.random(random_state=seed).as_matrix()
)
extents_strategy = arrays(np.float64, 3, elements=st.floats(0.01, 0.3))
centers_strategy = arrays(np.float64, 3, elements=st.floats(-2.0, 2.0))


@st.composite
def random_boxes(draw: st.DrawFn) -> Box:
    return Box(
        center=draw(centers_strategy), rotation=draw(rotations), extents=draw(extents_strategy)
    )


# One box -----------------------------------------------------------------------------------------


def test_one_box_gives_24_hypotheses_at_standoff_along_negative_normals():
    box = Box(
        center=[0.3, -0.2, 0.9],
        rotation=Rotation.from_euler('xyz', [20, -35, 70], degrees=True).as_matrix(),
        extents=[0.04, 0.06, 0.1],
    )
    standoff = 0.07
    grasps = grasp_hypotheses([box], gripper_max_width=WIDE, standoff=standoff)
    stats = grasp_filter_counts([box], gripper_max_width=WIDE, standoff=standoff)
    assert len(grasps) == HYPOTHESES_PER_BOX == 24
    assert stats.hypotheses == stats.after_occlusion == stats.after_support == 24
    normals, centers = box.face_normals(), box.face_centers()
    per_face = {name: [] for name in FACE_NAMES}
    for grasp in grasps:
        per_face[grasp.face_name].append(grasp)
        np.testing.assert_allclose(grasp.approach, -normals[grasp.face], atol=1e-12)
        np.testing.assert_allclose(
            grasp.position, centers[grasp.face] + standoff * normals[grasp.face], atol=1e-12
        )
        assert abs(np.linalg.norm(grasp.position - centers[grasp.face]) - standoff) < 1e-12
    for name, group in per_face.items():
        assert sorted(grasp.roll_deg for grasp in group) == [0, 90, 180, 270], name
        closings = np.array([grasp.closing for grasp in group])
        # Four distinct edge directions: two opposite pairs, each along a box axis in the face.
        assert np.allclose(closings[0], -closings[2]) and np.allclose(closings[1], -closings[3])
        assert abs(closings[0] @ closings[1]) < 1e-12
        in_box_frame = np.abs(closings @ box.rotation)
        assert np.allclose(np.sort(in_box_frame, axis=1), [0.0, 0.0, 1.0])


def test_roll_turns_the_closing_direction_about_the_approach():
    box = Box(center=[0, 0, 0], rotation=np.eye(3), extents=[0.02, 0.05, 0.07])
    grasps = grasp_hypotheses([box], gripper_max_width=WIDE)
    by_key = {(grasp.face, grasp.roll_deg): grasp for grasp in grasps}
    for face in range(6):
        base = by_key[(face, 0)]
        for roll in (90, 180, 270):
            turn = Rotation.from_rotvec(np.deg2rad(roll) * base.approach)
            np.testing.assert_allclose(
                by_key[(face, roll)].closing, turn.apply(np.array(base.closing)), atol=1e-12
            )
    # Roll 0 closes along the next box axis in cyclic order: +-x faces along y, +-z along x.
    np.testing.assert_allclose(by_key[(0, 0)].closing, [0, 1, 0])
    np.testing.assert_allclose(by_key[(3, 0)].closing, [0, 0, 1])
    np.testing.assert_allclose(by_key[(5, 0)].closing, [1, 0, 0])


@pytest.mark.parametrize('approach_axis', ['z', 'x'])
def test_quaternions_are_unit_and_map_gripper_axes_to_approach_and_closing(approach_axis):
    box = Box(
        center=[1.0, 2.0, -0.5],
        rotation=Rotation.from_euler('zyx', [10, 50, -25], degrees=True).as_matrix(),
        extents=[0.03, 0.05, 0.08],
    )
    grasps = grasp_hypotheses([box], gripper_max_width=WIDE, approach_axis=approach_axis)
    assert len(grasps) == 24
    for grasp in grasps:
        assert abs(np.linalg.norm(grasp.quaternion) - 1.0) < 1e-12
        assert grasp.quaternion[3] >= 0.0
        matrix = Rotation.from_quat(grasp.quaternion).as_matrix()
        assert abs(np.linalg.det(matrix) - 1.0) < 1e-12
        np.testing.assert_allclose(matrix[:, AXIS_INDEX[approach_axis]], grasp.approach,
                                   atol=1e-12)  # fmt: skip
        np.testing.assert_allclose(matrix[:, 1], grasp.closing, atol=1e-12)
        # Right-handed: the third axis is the cross product of the other two.
        np.testing.assert_allclose(np.cross(matrix[:, 0], matrix[:, 1]), matrix[:, 2], atol=1e-12)
        np.testing.assert_allclose(grasp.rotation, matrix, atol=1e-12)


def test_both_conventions_give_the_same_hypotheses_with_different_orientations():
    box = Box(center=[0, 0, 0], rotation=np.eye(3), extents=[0.03, 0.05, 0.08])
    along_z = grasp_hypotheses([box], gripper_max_width=WIDE, approach_axis='z')
    along_x = grasp_hypotheses([box], gripper_max_width=WIDE, approach_axis='x')
    for first, second in zip(along_z, along_x, strict=True):
        assert (first.face, first.roll_deg) == (second.face, second.roll_deg)
        np.testing.assert_array_equal(first.position, second.position)
        # The x convention is the z convention turned by -90 degrees about the closing (y) axis.
        relative = Rotation.from_quat(first.quaternion).inv() * Rotation.from_quat(
            second.quaternion
        )
        np.testing.assert_allclose(relative.as_rotvec(), [0, -np.pi / 2, 0], atol=1e-12)


# Occlusion ---------------------------------------------------------------------------------------


def test_two_touching_boxes_lose_exactly_their_touching_faces():
    lower = axis_box([0, 0, 0], [0.1, 0.06, 0.04])
    upper = axis_box([0.02, 0.01, 0.04], [0.08, 0.05, 0.09])  # sits on lower's top, smaller
    grasps = grasp_hypotheses([lower, upper], gripper_max_width=WIDE)
    stats = grasp_filter_counts([lower, upper], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(2) - {(0, '+z'), (1, '-z')}
    assert stats.faces_unoccluded == 10
    assert stats.after_occlusion == len(grasps) == 40


@pytest.mark.parametrize('gap', [0.0, 0.0005, -0.0005])
def test_small_gaps_and_overlaps_between_siblings_count_as_touching(gap):
    left = axis_box([0, 0, 0], [0.05, 0.04, 0.06])
    right = axis_box([0.05 + gap, 0, 0], [0.1, 0.04, 0.06])
    grasps = grasp_hypotheses([left, right], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(2) - {(0, '+x'), (1, '-x')}


def test_gap_wider_than_the_tolerance_does_not_occlude():
    # Default tolerance: 10 % of the smaller middle extent, 0.1 * 0.05 = 5 mm.
    left = axis_box([0, 0, 0], [0.05, 0.04, 0.06])
    right = axis_box([0.056, 0, 0], [0.106, 0.04, 0.06])
    assert face_set(grasp_hypotheses([left, right], gripper_max_width=WIDE)) == all_faces(2)
    occluded = grasp_hypotheses([left, right], gripper_max_width=WIDE, contact_tolerance=0.007)
    assert face_set(occluded) == all_faces(2) - {(0, '+x'), (1, '-x')}
    loose = grasp_hypotheses([left, right], gripper_max_width=WIDE, contact_fraction=0.15)
    assert face_set(loose) == face_set(occluded)


def test_neighbours_sharing_only_an_edge_do_not_occlude():
    lower = axis_box([0, 0, 0], [0.05, 0.05, 0.05])
    diagonal = axis_box([0.05, 0, 0.05], [0.1, 0.05, 0.1])  # shares lower's edge x=0.05, z=0.05
    beside_top = axis_box([0.05, 0, 0.0], [0.1, 0.05, 0.06])  # taller neighbour along +x
    assert face_set(grasp_hypotheses([lower, diagonal], gripper_max_width=WIDE)) == all_faces(2)
    grasps = grasp_hypotheses([lower, beside_top], gripper_max_width=WIDE)
    # The taller neighbour covers lower's +x face only; lower's top face stays free.
    assert face_set(grasps) == all_faces(2) - {(0, '+x'), (1, '-x')}


def test_small_box_partly_covering_a_big_face_occludes_it_and_the_occlusion_is_rotation_free():
    big = axis_box([-0.1, -0.1, -0.02], [0.1, 0.1, 0.0])
    small = Box(
        center=[0.05, 0.05, 0.0101],
        rotation=Rotation.from_euler('z', 30, degrees=True).as_matrix(),
        extents=[0.02, 0.02, 0.02],
    )
    grasps = grasp_hypotheses([big, small], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(2) - {(0, '+z'), (1, '-z')}


def test_box_standing_on_an_edge_occludes_by_the_45_degree_rule():
    # A cube turned by 30 degrees about y stands on one edge on the big box's top face, which it
    # touches along that line: the top face is occluded. Of the two cube faces meeting at the
    # edge, the one at 30 degrees to the top face comes within tol of it beyond the inset rim
    # (occluded); the one at 60 degrees does not (kept).
    big = axis_box([-0.1, -0.1, -0.02], [0.1, 0.1, 0.0])
    half = 0.01
    lowest = half * (np.sin(np.pi / 6) + np.cos(np.pi / 6))
    cube = Box(
        center=[0.0, 0.0, lowest],
        rotation=Rotation.from_euler('y', 30, degrees=True).as_matrix(),
        extents=[2 * half] * 3,
    )
    assert cube.corners()[:, 2].min() == pytest.approx(0.0, abs=1e-15)
    normals = dict(zip(FACE_NAMES, cube.face_normals(), strict=True))
    assert normals['-z'][2] == pytest.approx(-np.cos(np.pi / 6))  # 30 degrees to the table
    assert normals['+x'][2] == pytest.approx(-np.sin(np.pi / 6))  # 60 degrees to the table
    grasps = grasp_hypotheses([big, cube], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(2) - {(0, '+z'), (1, '-z')}


def test_boxes_inside_or_through_another_lose_the_faces_it_covers():
    outer = axis_box([0, 0, 0], [0.1, 0.1, 0.1])
    inner = axis_box([0.04, 0.04, 0.04], [0.06, 0.06, 0.06])
    # Every face of the inner box lies inside the outer one; the outer box's faces are free.
    inside = grasp_hypotheses([outer, inner], gripper_max_width=WIDE)
    assert face_set(inside) == all_faces(1)
    crossing = axis_box([0.04, 0.04, 0.04], [0.06, 0.06, 0.2])  # pierces outer's top face
    grasps = grasp_hypotheses([outer, crossing], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(1) - {(0, '+z')} | {(1, '+z')}


# Width and support filters -----------------------------------------------------------------------


def test_width_filter_removes_exactly_the_closings_along_too_long_edges():
    box = Box(
        center=[0, 0, 0],
        rotation=Rotation.from_euler('x', 30, degrees=True).as_matrix(),
        extents=[0.03, 0.08, 0.12],
    )
    grasps = grasp_hypotheses([box], gripper_max_width=0.08)
    stats = grasp_filter_counts([box], gripper_max_width=0.08)
    # Every face keeps its closings along a (0.03) and b (0.08, equal to the limit: kept).
    assert stats.after_occlusion == 24
    assert stats.after_width == len(grasps) == 16
    closing_axes = {int(np.argmax(np.abs(box.rotation.T @ grasp.closing))) for grasp in grasps}
    assert closing_axes == {0, 1}
    for grasp in grasps:
        closing_axis = int(np.argmax(np.abs(box.rotation.T @ grasp.closing)))
        assert grasp.width == pytest.approx(box.extents[closing_axis])
        assert grasp.width <= 0.08
    assert len(grasp_hypotheses([box], gripper_max_width=0.02)) == 0


def test_up_direction_removes_only_the_bottom_face_even_when_tilted():
    for tilt in (0.0, 20.0, 30.0):
        rotation = Rotation.from_euler('xy', [tilt, tilt / 2], degrees=True).as_matrix()
        box = Box(center=[0, 0, 0.5], rotation=rotation, extents=[0.04, 0.05, 0.06])
        grasps = grasp_hypotheses([box], gripper_max_width=WIDE, up=[0, 0, 2.0])
        stats = grasp_filter_counts([box], gripper_max_width=WIDE, up=[0, 0, 2.0])
        bottom = FACE_NAMES[int(np.argmin(box.face_normals() @ [0, 0, 1]))]
        assert face_set(grasps) == all_faces(1) - {(0, bottom)}, tilt
        assert stats.after_width == 24 and stats.after_support == 20
        assert all(grasp.approach[2] <= np.sin(np.pi / 4) for grasp in grasps)


def test_approach_elevation_limit_is_applied_exactly():
    # Face normals at -30 degrees below horizontal: approaches 30 degrees upwards.
    box = Box(
        center=[0, 0, 0],
        rotation=Rotation.from_euler('y', 30, degrees=True).as_matrix(),
        extents=[0.04, 0.05, 0.06],
    )
    elevations = {
        grasp.face_name: np.degrees(np.arcsin(grasp.approach[2]))
        for grasp in grasp_hypotheses([box], gripper_max_width=WIDE)
    }
    upward = {name for name, elevation in elevations.items() if elevation > 25.0}
    assert len(upward) == 2  # one at 30 degrees, the bottom face at 60 degrees
    for limit, removed in ((20.0, upward), (45.0, {n for n in upward if elevations[n] > 45})):
        grasps = grasp_hypotheses(
            [box], gripper_max_width=WIDE, up=[0, 0, 1], max_approach_elevation_deg=limit
        )
        assert face_set(grasps) == all_faces(1) - {(0, name) for name in removed}


@pytest.mark.parametrize(('lift', 'expected'), [(0.0, 12), (0.02, 20)])
def test_support_plane_removes_bottom_face_and_fingers_below_the_clearance(lift, expected):
    # Box resting on (lift = 0) or hovering above the plane z = 0.
    box = axis_box([0, 0, lift], [0.04, 0.05, lift + 0.06])
    grasps = grasp_hypotheses([box], gripper_max_width=WIDE, support_plane=[0, 0, 3.0, 0.0])
    stats = grasp_filter_counts([box], gripper_max_width=WIDE, support_plane=[0, 0, 3.0, 0.0])
    assert stats.after_width == 24 and stats.after_support == len(grasps) == expected
    assert (0, '-z') not in face_set(grasps)
    vertical_closings = [grasp for grasp in grasps if abs(grasp.closing[2]) > 0.5]
    if lift == 0.0:
        # Resting: side grasps closing vertically would put a finger into the table.
        assert vertical_closings == []
    else:
        assert len(vertical_closings) == 8
    for grasp in grasps:
        assert grasp.position[2] >= 0.01


def test_support_plane_in_a_tilted_sensor_frame_matches_the_upright_result():
    box = axis_box([0, 0, 0], [0.04, 0.05, 0.06])
    upright = grasp_hypotheses([box], gripper_max_width=WIDE, support_plane=[0, 0, 1, 0])
    motion = Rotation.from_euler('xyz', [-110, 10, 5], degrees=True)
    shift = np.array([0.1, 0.3, 0.9])
    moved = box.transformed(motion.as_matrix(), shift)
    normal = motion.apply([0, 0, 1])
    plane = np.append(normal, -normal @ shift) * 0.5
    tilted = grasp_hypotheses([moved], gripper_max_width=WIDE, support_plane=plane)
    assert face_set(tilted) == face_set(upright)
    assert len(tilted) == len(upright) == 12


def test_clearance_removes_a_low_standoff_position():
    # A box lying on its side, tilted so that a side face looks slightly downwards: its
    # pre-grasp position hangs below the clearance although the direction test keeps it.
    box = Box(
        center=[0, 0, 0.03],
        rotation=Rotation.from_euler('y', 40, degrees=True).as_matrix(),
        extents=[0.04, 0.05, 0.04],
    )
    grasps = grasp_hypotheses(
        [box], gripper_max_width=WIDE, standoff=0.1, support_plane=[0, 0, 1, 0]
    )
    for grasp in grasps:
        assert grasp.position[2] >= 0.01
    no_clearance = grasp_hypotheses([box], gripper_max_width=WIDE, standoff=0.1, up=[0, 0, 1])
    assert {g.face_name for g in no_clearance} - {g.face_name for g in grasps}


# Strategies --------------------------------------------------------------------------------------


def strategy_scene() -> list[Box]:
    return [
        axis_box([0.0, 0.0, 0.0], [0.04, 0.04, 0.04]),  # 0: medium, near origin
        axis_box([0.5, 0.0, 0.0], [0.56, 0.06, 0.06]),  # 1: largest, far out
        axis_box([0.1, 0.0, 0.0], [0.12, 0.02, 0.02]),  # 2: smallest
        axis_box([0.2, 0.0, 0.0], [0.24, 0.04, 0.04]),  # 3: same size as 0
    ]


def box_order(grasps: list[Grasp]) -> list[int]:
    return [index for index, _ in itertools.groupby(grasp.box_index for grasp in grasps)]


@pytest.mark.parametrize(
    ('strategy', 'expected'),
    [
        ('largest', [1, 0, 3, 2]),  # 0 and 3 tie on volume (up to rounding): box index decides
        ('smallest', [2, 0, 3, 1]),
        ('nearest', [0, 2, 3, 1]),
        ('outermost', [0, 2, 1, 3]),  # volume-weighted centroid ~ (0.37, 0.026, 0.026)
    ],
)
def test_strategies_order_boxes_as_documented(strategy, expected):
    grasps = grasp_hypotheses(strategy_scene(), gripper_max_width=WIDE, strategy=strategy)
    assert len(grasps) == 4 * 24
    assert box_order(grasps) == expected
    scores = [grasp.score for grasp in grasps]
    assert scores == sorted(scores, reverse=True)
    assert scores[0] == 1.0 and scores[-1] == 0.0
    # Within a box: face index, then roll.
    first_box = [(grasp.face, grasp.roll_deg) for grasp in grasps[:24]]
    assert first_box == sorted(first_box)


def test_nearest_uses_the_sensor_origin_and_outermost_the_decomposition_points():
    boxes = strategy_scene()
    grasps = grasp_hypotheses(
        boxes, gripper_max_width=WIDE, strategy='nearest', sensor_origin=[0.6, 0, 0]
    )
    assert box_order(grasps) == [1, 3, 2, 0]
    # Points concentrated at x = 0.53 put the centroid inside box 1: box 0 is then outermost.
    points = np.array([[0.53, 0.03, 0.03]] * 10 + [[0.02, 0.02, 0.02]])
    decomposition = decomposition_of(boxes, points)
    outer = grasp_hypotheses(decomposition, gripper_max_width=WIDE, strategy='outermost')
    centroid = points.mean(axis=0)
    distances = [np.linalg.norm(box.center - centroid) for box in boxes]
    assert box_order(outer) == list(np.argsort(distances)[::-1])
    assert box_order(outer)[0] == 0


def test_scores_do_not_depend_on_the_filters():
    boxes = strategy_scene()
    every = {g.box_index: g.score for g in grasp_hypotheses(boxes, gripper_max_width=WIDE)}
    narrow = grasp_hypotheses(boxes, gripper_max_width=0.045)
    assert 1 not in {g.box_index for g in narrow}  # the largest box is too wide everywhere
    for grasp in narrow:
        assert grasp.score == every[grasp.box_index]


# Inputs and stats --------------------------------------------------------------------------------


def test_decomposition_leaves_and_empty_input():
    box = axis_box([0, 0, 0], [0.02, 0.03, 0.04])
    decomposition = decomposition_of([box], box.corners())
    assert decomposition.leaves == [box]
    assert len(grasp_hypotheses(decomposition)) == len(grasp_hypotheses([box])) == 24
    grasps = grasp_hypotheses([])
    stats = grasp_filter_counts([])
    assert grasps == [] and stats.hypotheses == 0 and stats.after_support == 0


@pytest.mark.parametrize(
    'options',
    [
        {'strategy': 'biggest'},
        {'approach_axis': 'y'},
        {'gripper_max_width': 0.0},
        {'standoff': -0.01},
        {'up': [0, 0, 0]},
        {'support_plane': [0, 0, 1]},
        {'max_approach_elevation_deg': 100.0},
        {'contact_tolerance': -1.0},
    ],
)
def test_invalid_parameters_raise(options):
    with pytest.raises(ValueError):
        grasp_hypotheses([axis_box([0, 0, 0], [1, 1, 1])], **options)


def test_non_box_input_raises_type_error():
    with pytest.raises(TypeError):
        grasp_hypotheses(3.0)
    with pytest.raises(TypeError):
        grasp_hypotheses([(0, 0, 0)])
    with pytest.raises(TypeError, match='sequence of Box'):
        grasp_hypotheses(axis_box([0, 0, 0], [1, 1, 1]))  # one box: pass [box]


def test_max_grasps_keeps_the_best_and_does_not_change_the_counts():
    boxes = strategy_scene()
    every = grasp_hypotheses(boxes, gripper_max_width=WIDE)
    best = grasp_hypotheses(boxes, gripper_max_width=WIDE, max_grasps=5)
    assert [repr(g) for g in best] == [repr(g) for g in every[:5]]
    stats = grasp_filter_counts(boxes, gripper_max_width=WIDE, max_grasps=5)
    assert stats.after_support == len(every) > 5
    with pytest.raises(ValueError, match='max_grasps'):
        grasp_hypotheses(boxes, max_grasps=-1)


def test_stats_count_each_filter_in_order():
    lower = axis_box([0, 0, 0], [0.1, 0.06, 0.04])
    upper = axis_box([0.02, 0.01, 0.04], [0.08, 0.05, 0.09])
    grasps = grasp_hypotheses([lower, upper], gripper_max_width=0.07, up=[0, 0, 1])
    stats = grasp_filter_counts([lower, upper], gripper_max_width=0.07, up=[0, 0, 1])
    # Occlusion: lower +z and upper -z (8). Width: lower's closings along x (0.1 > 0.07) on
    # its unoccluded faces with an x edge, +-y and -z (6). Support: lower's -z face, whose two
    # closings along y are left (2).
    assert stats.as_dict() == {
        'boxes': 2,
        'faces': 12,
        'faces_unoccluded': 10,
        'faces_graspable': 9,
        'hypotheses': 48,
        'after_occlusion': 40,
        'after_width': 34,
        'after_support': 32,
    }
    assert len(grasps) == stats.after_support
    json_ready = grasps[0].to_dict()
    assert json_ready['face_name'] == grasps[0].face_name and len(json_ready['quaternion']) == 4


# Exact separating-axis test against a linear program ---------------------------------------------


def growth_to_touch(first: Box, second: Box) -> float:
    """Smallest s such that both boxes grown by s on every side intersect (s < 0: overlap)."""
    rows, bounds = [], []
    for box in (first, second):
        for axis in range(3):
            direction = box.rotation[:, axis]
            offset = direction @ box.center
            for sign in (1.0, -1.0):  # sign * (d . x - offset) - s <= h
                rows.append(np.append(sign * direction, -1.0))
                bounds.append(box.half_extents[axis] + sign * offset)
    result = linprog(
        c=[0, 0, 0, 1.0], A_ub=np.array(rows), b_ub=np.array(bounds), bounds=[(None, None)] * 4
    )
    assert result.status == 0
    return float(result.fun)


@settings(max_examples=150, deadline=None)
@given(random_boxes(), random_boxes(), st.floats(0.0, 1.0))
def test_separating_axis_test_agrees_with_a_linear_program(first, second, pull):
    # Pull the second box towards the first so that both outcomes occur.
    second = Box(
        center=first.center + pull * (second.center - first.center),
        rotation=second.rotation,
        extents=second.extents,
    )
    growth = growth_to_touch(first, second)
    result = boxes_intersect(
        first.center, first.rotation, first.half_extents,
        second.center, second.rotation, second.half_extents,
    )  # fmt: skip
    if growth > 1e-7:
        assert not result
    elif growth < -1e-7:
        assert result


# Properties under random boxes and rigid motions -------------------------------------------------


def check_hypotheses_on_their_boxes(grasps: list[Grasp], boxes: list[Box], standoff: float):
    for grasp in grasps:
        box = boxes[grasp.box_index]
        normal = box.face_normals()[grasp.face]
        np.testing.assert_allclose(grasp.approach, -normal, atol=1e-9)
        np.testing.assert_allclose(
            grasp.position, box.face_centers()[grasp.face] + standoff * normal, atol=1e-9
        )
        assert abs(grasp.closing @ grasp.approach) < 1e-9
        assert abs(np.linalg.norm(grasp.closing) - 1.0) < 1e-9
        along = np.abs(box.rotation.T @ grasp.closing)
        assert np.isclose(along.max(), 1.0)
        assert grasp.width == pytest.approx(box.extents[int(np.argmax(along))], abs=1e-12)
        assert abs(np.linalg.norm(grasp.quaternion) - 1.0) < 1e-9


@settings(max_examples=40, deadline=None)
@given(
    random_boxes(),
    st.sampled_from([0, 1, 2]),
    st.floats(0.2, 0.8),
    st.floats(-0.8, 0.8),
    rotations,
    centers_strategy,
    st.floats(0.0, 0.1),
    st.sampled_from(['largest', 'smallest', 'outermost', 'nearest']),
)
def test_split_box_siblings_lose_their_facing_faces_under_any_rigid_motion(
    box, axis, cut, gap_fraction, motion, shift, standoff, strategy
):
    # Split a random box across one axis with a gap (or overlap, gap < 0) within the default
    # contact tolerance, which is at least 0.1 * 0.96 * min(cut, 1 - cut) * smallest extent.
    extent = box.extents[axis]
    gap = gap_fraction * 0.1 * min(cut, 1.0 - cut) * box.extents.min()
    sizes_low, sizes_high = box.extents.copy(), box.extents.copy()
    sizes_low[axis] = cut * extent - gap / 2
    sizes_high[axis] = (1.0 - cut) * extent - gap / 2
    direction = box.rotation[:, axis]
    low = Box(
        center=box.center + direction * (-extent / 2 + sizes_low[axis] / 2),
        rotation=box.rotation,
        extents=sizes_low,
    )
    high = Box(
        center=box.center + direction * (extent / 2 - sizes_high[axis] / 2),
        rotation=box.rotation,
        extents=sizes_high,
    )
    scene = [low, high]
    options = {'gripper_max_width': 0.2, 'standoff': standoff, 'strategy': strategy,
               'up': [0.0, 0.0, 1.0], 'sensor_origin': [0.0, 0.0, 0.0]}  # fmt: skip
    grasps = grasp_hypotheses(scene, **options)
    stats = grasp_filter_counts(scene, **options)
    facing = {(0, FACE_NAMES[2 * axis]), (1, FACE_NAMES[2 * axis + 1])}
    assert face_set(grasps).isdisjoint(facing)
    assert stats.faces_unoccluded == 10
    check_hypotheses_on_their_boxes(grasps, scene, standoff)

    moved_scene = [part.transformed(motion, shift) for part in scene]
    moved_options = dict(options, up=motion @ [0.0, 0.0, 1.0], sensor_origin=shift)
    moved = grasp_hypotheses(moved_scene, **moved_options)
    moved_stats = grasp_filter_counts(moved_scene, **moved_options)
    assert moved_stats == stats
    keys = [(g.box_index, g.face, g.roll_deg) for g in grasps]
    moved_keys = [(g.box_index, g.face, g.roll_deg) for g in moved]
    assert moved_keys == keys  # keys that differ by rounding only tie: order by box index
    check_hypotheses_on_their_boxes(moved, moved_scene, standoff)
    by_key = dict(zip(moved_keys, moved, strict=True))
    for key, before in zip(keys, grasps, strict=True):
        after = by_key[key]
        np.testing.assert_allclose(after.approach, motion @ before.approach, atol=1e-9)
        np.testing.assert_allclose(after.position, motion @ before.position + shift, atol=1e-9)
        turned = Rotation.from_matrix(motion) * Rotation.from_quat(before.quaternion)
        assert (Rotation.from_quat(after.quaternion).inv() * turned).magnitude() < 1e-7


@settings(max_examples=40, deadline=None)
@given(st.lists(random_boxes(), min_size=1, max_size=4), rotations, centers_strategy,
       st.floats(0.02, 0.3))  # fmt: skip
def test_counts_are_invariant_under_rigid_motion_of_random_scenes(boxes, motion, shift, width):
    grasps = grasp_hypotheses(boxes, gripper_max_width=width)
    stats = grasp_filter_counts(boxes, gripper_max_width=width)
    moved = [box.transformed(motion, shift) for box in boxes]
    moved_grasps = grasp_hypotheses(moved, gripper_max_width=width)
    moved_stats = grasp_filter_counts(moved, gripper_max_width=width)
    assert moved_stats == stats
    assert stats.hypotheses == 24 * len(boxes)
    assert stats.hypotheses >= stats.after_occlusion >= stats.after_width >= stats.after_support
    assert len(grasps) == len(moved_grasps) == stats.after_support
    check_hypotheses_on_their_boxes(grasps, boxes, 0.05)
    for grasp in grasps:
        assert grasp.width <= width


@settings(max_examples=60, deadline=None)
@given(random_boxes(), arrays(np.float64, 3, elements=st.floats(-1.0, 1.0)))
def test_direction_test_removes_at_most_the_bottom_face(box, up):
    if np.linalg.norm(up) < 1e-3:
        up = np.array([0.0, 0.0, 1.0])
    up_unit = up / np.linalg.norm(up)
    grasps = grasp_hypotheses([box], gripper_max_width=WIDE, up=up)
    removed = all_faces(1) - face_set(grasps)
    downward = box.face_normals() @ up_unit
    assert len(removed) <= 1
    if removed:
        assert removed == {(0, FACE_NAMES[int(np.argmin(downward))])}
    assert removed == {
        (0, name) for name, d in zip(FACE_NAMES, downward, strict=True) if d < -np.sqrt(0.5)
    }
    assert len(grasps) == 24 - 4 * len(removed)


def test_box_sizes_are_middle_extents_and_flat_boxes_keep_their_face_size():
    sizes = grasp_module.box_sizes([[0.03, 0.01, 0.2], [0.0, 0.1, 0.05], [0.0, 0.0, 0.3]])
    np.testing.assert_allclose(sizes, [0.03, 0.05, 0.3])


def test_flat_boxes_stacked_with_a_gap_occlude_each_other():
    # Two planar patches (zero thickness) 4 mm apart: 0.1 of their 0.05 face size is 5 mm.
    lower = axis_box([0, 0, 0], [0.05, 0.06, 0.0])
    upper = axis_box([0, 0, 0.004], [0.05, 0.06, 0.004])
    grasps = grasp_hypotheses([lower, upper], gripper_max_width=WIDE)
    assert face_set(grasps) == all_faces(2) - {(0, '+z'), (1, '-z')}


def test_outermost_centroid_ignores_points_dropped_as_noise():
    boxes = strategy_scene()
    points = np.array([[0.02, 0.02, 0.02], [0.22, 0.02, 0.02], [50.0, 0.0, 0.0]])
    # With the far outlier the centroid is near x = 16.7 and box 0 (x = 0.02) is outermost;
    # without it (dropped as noise) the centroid is at x = 0.12 and box 1 (x = 0.53) is.
    everything = decomposition_of(boxes, points)
    order = box_order(grasp_hypotheses(everything, strategy='outermost', gripper_max_width=WIDE))
    assert order[0] == 0
    kept = decomposition_of(boxes, points, kept_point_indices=[0, 1])
    order = box_order(grasp_hypotheses(kept, strategy='outermost', gripper_max_width=WIDE))
    assert order[0] == 1


@pytest.mark.parametrize('gain_threshold', [0.90, 0.98])
def test_real_bunny_decomposition(shared_data, gain_threshold):
    decomposition_module = pytest.importorskip('mvbb_ros.geometry.decomposition.tree')
    points = np.load(shared_data / 'models' / 'bunny_vertices.npy').astype(np.float64)  # metres
    decomposition = decomposition_module.decompose(points, gain_threshold=gain_threshold)
    leaves = decomposition.leaves
    up = [0.0, 1.0, 0.0]  # the bunny model stands on its y axis
    grasps = grasp_hypotheses(decomposition, up=up)
    stats = grasp_filter_counts(decomposition, up=up)
    assert stats.boxes == len(leaves) and stats.hypotheses == 24 * len(leaves)
    assert stats.hypotheses >= stats.after_occlusion >= stats.after_width >= stats.after_support
    assert len(grasps) == stats.after_support > 0
    check_hypotheses_on_their_boxes(grasps, leaves, 0.05)
    for grasp in grasps:
        assert grasp.width <= 0.08
        assert grasp.approach @ up <= np.sqrt(0.5) + 1e-12
        # A face whose centre lies inside another leaf is always occluded.
        center = leaves[grasp.box_index].face_centers()[grasp.face]
        others = [box for index, box in enumerate(leaves) if index != grasp.box_index]
        assert not any(box.contains(center[None], 0.0)[0] for box in others)
    if len(leaves) > 1:
        assert stats.after_occlusion < stats.hypotheses  # sibling boxes touch or overlap


def _occluded_faces_pairwise(centers, rotations, extents, fraction):
    """Apply the occlusion rule box pair by box pair (docs/grasp_rules.md): a slow reference."""
    count = len(centers)
    floor = 1e-9 * float(np.max(extents)) + 8.0 * np.finfo(float).eps * float(
        np.max(np.abs(centers))
    )
    sizes = grasp_module.box_sizes(extents)
    occluded = np.zeros((count, 6), dtype=bool)
    for owner, other in itertools.permutations(range(count), 2):
        tolerance = fraction * min(sizes[owner], sizes[other]) + floor
        depth = tolerance + floor
        half = extents[owner] / 2.0
        for face in range(6):
            axis, sign = face // 2, (-1.0 if face % 2 else 1.0)
            normal = sign * rotations[owner][:, axis]
            slab_half = np.maximum(half - tolerance, 0.0)
            slab_half[axis] = depth / 2.0
            centre = centers[owner] + normal * half[axis] + normal * (tolerance - depth / 2.0)
            occluded[owner, face] |= bool(
                boxes_intersect(
                    centre,
                    rotations[owner],
                    slab_half,
                    centers[other],
                    rotations[other],
                    extents[other] / 2.0,
                )
            )
    return occluded


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(2, 12), spread=st.floats(0.02, 0.5))
def test_property_occlusion_tests_only_near_pairs_and_agrees_with_every_pair(seed, count, spread):
    rng = np.random.default_rng(seed)
    extents = rng.uniform(0.005, 0.08, size=(count, 3))
    extents[rng.random(count) < 0.2, 0] = 0.0  # flat boxes too
    centers = rng.uniform(-spread, spread, size=(count, 3))
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    rotations[: count // 2] = np.eye(3)  # aligned neighbours share faces
    fraction = 0.05
    expected = _occluded_faces_pairwise(centers, rotations, extents, fraction)
    got = grasp_module._occluded_faces(centers, rotations, extents, None, fraction)
    np.testing.assert_array_equal(got, expected)


def test_occlusion_memory_grows_with_the_touching_pairs_not_with_every_pair():
    import tracemalloc

    rng = np.random.default_rng(7)
    count = 3000  # 300 blobs of ten boxes: the cluttered cloud that took gigabytes
    centers = rng.uniform(-0.85, 0.85, size=(count, 3))
    extents = rng.uniform(0.005, 0.03, size=(count, 3))
    rotations = Rotation.random(count, random_state=7).as_matrix()
    tracemalloc.start()
    occluded = grasp_module._occluded_faces(centers, rotations, extents, None, 0.05)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # All pairs at once were (6, B, B, 15, 3) float64 arrays: 19 GB here.
    assert peak < 200e6, f'{peak / 1e6:.0f} MB'
    assert occluded.shape == (count, 6) and occluded.any()
