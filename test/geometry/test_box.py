"""Box: construction checks, derived geometry, frames, containment and serialisation."""

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.geometry.box import Box, EDGES, FACE_NAMES, right_handed, rotation_quaternions
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _box(seed=0, center=(1.0, -2.0, 0.5), extents=(0.4, 0.2, 0.1)):
    rotation = Rotation.random(random_state=seed).as_matrix()
    return Box(center=center, rotation=rotation, extents=extents)


def test_box_rejects_bad_values():
    with pytest.raises(ValueError, match='extents must be >= 0'):
        Box(center=np.zeros(3), rotation=np.eye(3), extents=(1.0, -1.0, 1.0))
    with pytest.raises(ValueError, match='orthonormal'):
        Box(center=np.zeros(3), rotation=2.0 * np.eye(3), extents=np.ones(3))
    with pytest.raises(ValueError, match='right-handed'):
        Box(center=np.zeros(3), rotation=np.diag([1.0, 1.0, -1.0]), extents=np.ones(3))
    with pytest.raises(ValueError, match='finite'):
        Box(center=(np.nan, 0.0, 0.0), rotation=np.eye(3), extents=np.ones(3))
    with pytest.raises(ValueError, match='shape'):
        Box(center=np.zeros(2), rotation=np.eye(3), extents=np.ones(3))


def test_box_arrays_are_read_only_copies():
    center = np.array([1.0, 2.0, 3.0])
    box = Box(center=center, rotation=np.eye(3), extents=np.ones(3))
    center[0] = 9.0
    assert box.center[0] == 1.0
    with pytest.raises(ValueError):
        box.extents[0] = 5.0


def test_right_handed_flips_only_left_handed_frames():
    flipped = right_handed(np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(flipped) == pytest.approx(1.0)
    rotation = Rotation.random(random_state=3).as_matrix()
    np.testing.assert_array_equal(right_handed(rotation), rotation)


def test_corners_edges_and_faces_agree():
    box = _box()
    corners = box.corners()
    assert corners.shape == (8, 3)
    assert len(EDGES) == 12
    lengths = sorted(np.linalg.norm(corners[i] - corners[j]) for i, j in EDGES)
    np.testing.assert_allclose(lengths, np.repeat(sorted(box.extents), 4))
    normals = box.face_normals()
    centers = box.face_centers()
    assert normals.shape == centers.shape == (len(FACE_NAMES), 3)
    # Each face centre lies half an extent out along its outward normal, on the box surface.
    np.testing.assert_allclose(
        np.einsum('fd,fd->f', centers - box.center, normals), np.repeat(box.half_extents, 2)
    )
    np.testing.assert_allclose(
        np.abs(box.to_local(centers)).max(axis=1), box.half_extents[[0, 0, 1, 1, 2, 2]]
    )


def test_volume_and_quaternion():
    box = _box(extents=(2.0, 3.0, 4.0))
    assert box.volume == pytest.approx(24.0)
    quaternion = box.quaternion
    assert quaternion[3] >= 0.0
    np.testing.assert_allclose(
        Rotation.from_quat(quaternion).as_matrix(), box.rotation, atol=1e-12
    )


_UNIT_VECTORS = st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: 1e-3 < float(np.linalg.norm(q))
)


@settings(max_examples=200, deadline=None)
@given(st.lists(_UNIT_VECTORS, min_size=1, max_size=8))
def test_quaternions_give_back_the_rotations(vectors):
    # Any unit quaternion (half turns, turns about one axis, the identity among them).
    turns = Rotation.from_quat(np.array(vectors)).as_matrix()
    corners = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
    matrices = np.concatenate([turns, corners])
    quaternions = rotation_quaternions(matrices)
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, atol=1e-12)
    assert np.all(quaternions[:, 3] >= 0.0)
    np.testing.assert_allclose(Rotation.from_quat(quaternions).as_matrix(), matrices, atol=1e-12)


def test_quaternions_refuse_what_is_not_a_rotation():
    with pytest.raises(ValueError, match='determinant'):
        rotation_quaternions(np.diag([1.0, 1.0, -1.0])[None])
    with pytest.raises(ValueError, match=r'\(N, 3, 3\)'):
        rotation_quaternions(np.eye(3))


def test_enclosing_is_tight_and_keeps_precision_far_away():
    rng = np.random.default_rng(1)
    rotation = Rotation.random(random_state=2).as_matrix()
    local = rng.uniform(-1.0, 1.0, size=(500, 3)) * [1e-3, 5e-4, 2e-4]
    points = local @ rotation.T + [1e6, -2e6, 5e5]
    box = Box.enclosing(points, rotation)
    assert box.contains(points).all()
    np.testing.assert_allclose(box.extents, np.ptp(local, axis=0), rtol=1e-6)
    axis_aligned = Box.enclosing(points)
    np.testing.assert_array_equal(axis_aligned.rotation, np.eye(3))
    np.testing.assert_allclose(axis_aligned.extents, np.ptp(points, axis=0))


def test_enclosing_rejects_no_points():
    with pytest.raises(ValueError, match='at least one point'):
        Box.enclosing(np.zeros((0, 3)))


def test_contains_uses_the_tolerance():
    box = Box(center=np.zeros(3), rotation=np.eye(3), extents=(2.0, 2.0, 2.0))
    points = np.array([[1.0, 0.0, 0.0], [1.0 + 1e-12, 0.0, 0.0], [1.1, 0.0, 0.0]])
    np.testing.assert_array_equal(box.contains(points), [True, True, False])
    np.testing.assert_array_equal(box.contains(points, tol=0.2), [True, True, True])
    np.testing.assert_array_equal(box.contains(points, tol=0.0), [True, False, False])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.floats(0.0, 0.05))
def test_property_contains_is_the_box_frame_test(seed, tol):
    rng = np.random.default_rng(seed)
    box = _box(seed % 1000, center=rng.normal(size=3), extents=rng.uniform(0.0, 1.0, 3))
    points = box.center + rng.normal(size=(300, 3)) * 0.5
    points[:3] = box.corners()[:3]  # on the boundary: inside with the default tolerance
    slack = np.abs(box.to_local(points)) - (box.half_extents + tol)
    expected = np.all(slack <= 0.0, axis=1)
    clear = np.all(np.abs(slack) > 1e-12, axis=1)  # rounding decides nothing here
    np.testing.assert_array_equal(box.contains(points, tol=tol)[clear], expected[clear])
    assert box.contains(points[:3]).all()


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    translation=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
)
def test_frames_round_trip_and_rigid_motion(seed, translation):
    box = _box(seed)
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(20, 3))
    np.testing.assert_allclose(box.to_world(box.to_local(points)), points, atol=1e-9)
    motion = Rotation.random(random_state=seed + 1).as_matrix()
    moved = box.transformed(motion, translation)
    expected = box.corners() @ motion.T + np.asarray(translation)
    # The same box: every moved corner is a corner of the moved box.
    distances = np.linalg.norm(expected[:, None] - moved.corners()[None], axis=2)
    assert distances.min(axis=1).max() < 1e-9 * (1.0 + np.abs(translation).max())
    assert moved.volume == pytest.approx(box.volume)


def test_dict_round_trip():
    box = _box(7)
    again = Box.from_dict(box.to_dict())
    np.testing.assert_allclose(again.center, box.center)
    np.testing.assert_allclose(again.rotation, box.rotation, atol=1e-12)
    np.testing.assert_allclose(again.extents, box.extents)
    assert box.to_dict()['volume'] == pytest.approx(box.volume)


def test_trusted_boxes_take_their_arrays_over_read_only():
    """Box.trusted is for kernel outputs: no checks and no copies, but no writable arrays."""
    center, rotation, extents = np.array([1.0, 2.0, 3.0]), np.eye(3), np.array([0.3, 0.2, 0.1])
    box = Box.trusted(center, rotation, extents)
    assert box.center is center and box.rotation is rotation and box.extents is extents
    assert not any(array.flags.writeable for array in (center, rotation, extents))
    checked = Box(center=center, rotation=rotation, extents=extents)
    assert box.volume == checked.volume
    np.testing.assert_array_equal(box.corners(), checked.corners())
    with pytest.raises(ValueError, match='read-only'):
        box.center[0] = 0.0
