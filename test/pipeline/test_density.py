"""Small objects sampled again, finer: more of their own points, nothing of their neighbours."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline.density import finer_object_points, largest_extent, object_voxel_size
from mvbb_ros.pipeline.filtering import filter_points
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

VOXEL = 0.005


def box_surface(size: tuple[float, float, float], spacing: float, seed: int) -> np.ndarray:
    """Return a box's five faces but the bottom, sampled about every `spacing`, with noise."""
    rng = np.random.default_rng(seed)
    sx, sy, sz = size
    faces = []
    for area, sample in (
        (sx * sy, lambda n: np.c_[rng.uniform(0, sx, n), rng.uniform(0, sy, n), np.full(n, sz)]),
        (sx * sz, lambda n: np.c_[rng.uniform(0, sx, n), np.zeros(n), rng.uniform(0, sz, n)]),
        (sx * sz, lambda n: np.c_[rng.uniform(0, sx, n), np.full(n, sy), rng.uniform(0, sz, n)]),
        (sy * sz, lambda n: np.c_[np.zeros(n), rng.uniform(0, sy, n), rng.uniform(0, sz, n)]),
        (sy * sz, lambda n: np.c_[np.full(n, sx), rng.uniform(0, sy, n), rng.uniform(0, sz, n)]),
    ):
        faces.append(sample(max(1, int(area / spacing**2))))
    points = np.concatenate(faces) + rng.normal(0.0, 0.0003, (sum(map(len, faces)), 3))
    return points + np.array([0.0, 0.0, 0.6])  # in front of the sensor


def coarse(points: np.ndarray) -> np.ndarray:
    return filter_points(points, voxel_size=VOXEL, outlier_neighbors=20)[0]


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_the_largest_extent_does_not_depend_on_the_objects_rotation(seed):
    points = box_surface((0.04, 0.025, 0.012), 0.002, seed % 1000)
    turned = points @ Rotation.random(random_state=seed).as_matrix().T
    assert abs(largest_extent(turned) - largest_extent(points)) < 1e-9
    assert 0.04 <= largest_extent(points) <= np.linalg.norm([0.04, 0.025, 0.012]) + 0.002


@settings(max_examples=40, deadline=None)
@given(
    st.floats(0.0, 1.0),
    st.integers(1, 200),
    st.floats(1e-4, 0.01),
    st.floats(1e-4, 0.02),
)
def test_an_objects_voxel_lies_between_the_finest_and_the_frames(extent, cells, finest, frame):
    points = np.array([[0.0, 0.0, 0.0], [extent, 0.0, 0.0]])
    edge = object_voxel_size(points, frame, cells, finest)
    assert min(finest, frame) <= edge <= frame
    if finest <= extent / cells <= frame:
        assert edge == extent / cells
    assert object_voxel_size(points, frame, 0, finest) == frame


def test_a_small_object_gets_more_of_its_own_points_and_a_large_one_keeps_its_own():
    small = box_surface((0.04, 0.025, 0.012), 0.001, 0)
    observed = coarse(small)
    finer = finer_object_points(observed, small, VOXEL, 30, 0.002, 20, 2.0)
    assert finer is not None
    assert finer.voxel_size == 0.002  # 4 cm / 30 is below the finest edge
    assert len(finer.points) > 3 * len(observed)
    # Every finer point is near the object's own raw points.
    distances, _ = cKDTree(small).query(finer.points)
    assert distances.max() < finer.voxel_size * np.sqrt(3.0)
    large = box_surface((0.2, 0.15, 0.1), 0.002, 1)
    assert finer_object_points(coarse(large), large, VOXEL, 30, 0.002, 20, 2.0) is None
    assert finer_object_points(observed, small, VOXEL, 0, 0.002, 20, 2.0) is None


def test_the_finer_points_leave_a_neighbour_out():
    small = box_surface((0.04, 0.025, 0.012), 0.001, 2)
    neighbour = box_surface((0.04, 0.025, 0.012), 0.001, 3) + np.array([0.03, 0.0, 0.0])
    # The neighbour overlaps the object's bounds' margin: only its points beyond 3 cm are in the
    # cloud, so its nearest points stand 2.6 cm from the object (more than a cluster tolerance).
    neighbour = neighbour[neighbour[:, 0] > 0.066]
    cloud = np.concatenate([small, neighbour])
    observed = coarse(small)
    finer = finer_object_points(observed, cloud, VOXEL, 30, 0.002, 20, 2.0)
    assert finer is not None
    assert finer.points[:, 0].max() < 0.045


def test_the_pipeline_samples_a_small_object_finer_and_leaves_a_large_one_bit_for_bit():
    node = PipelineSettings().updated({'up_direction': [0.0, -1.0, 0.0]})
    off = node.updated({'object_voxel_cells': 0})
    small = box_surface((0.04, 0.025, 0.012), 0.001, 4)
    before = small.copy()
    fine, plain = process_points(small, node), process_points(small, off)
    np.testing.assert_array_equal(small, before)  # the input is never modified
    assert fine.objects[0].voxel_size < VOXEL == plain.objects[0].voxel_size
    assert fine.objects[0].shape.observed > 2 * plain.objects[0].shape.observed
    assert fine.objects[0].spacing < plain.objects[0].spacing
    large = box_surface((0.25, 0.2, 0.15), 0.002, 5)
    first, second = process_points(large, node), process_points(large, off)
    assert first.objects[0].voxel_size == VOXEL
    np.testing.assert_array_equal(first.objects[0].shape.points, second.objects[0].shape.points)
    assert [g.position.tolist() for g in first.grasps] == [
        g.position.tolist() for g in second.grasps
    ]


def test_the_same_finer_points_with_any_number_of_workers():
    small = box_surface((0.04, 0.025, 0.012), 0.001, 6)
    node = PipelineSettings().updated({'up_direction': [0.0, -1.0, 0.0]})
    one = process_points(small, replace(node, execution=replace(node.execution, workers=1)))
    two = process_points(small, replace(node, execution=replace(node.execution, workers=2)))
    np.testing.assert_array_equal(one.objects[0].shape.points, two.objects[0].shape.points)
    assert [g.position.tolist() for g in one.grasps] == [g.position.tolist() for g in two.grasps]


def _reference_near(observed: np.ndarray, raw: np.ndarray, voxel: float) -> np.ndarray:
    """Return the raw points in the bounds within a voxel's diagonal of `observed`, all queried."""
    reach = voxel * np.sqrt(3.0)
    low, high = observed.min(axis=0) - reach, observed.max(axis=0) + reach
    region = np.asarray(raw[np.all((raw >= low) & (raw <= high), axis=1)], dtype=np.float64)
    distances, _ = cKDTree(observed).query(region, distance_upper_bound=reach)
    return region[np.isfinite(distances)]


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    size=st.floats(0.03, 0.12),
    voxel=st.floats(0.002, 0.008),
    stray=st.integers(0, 300),
    dtype=st.sampled_from([np.float32, np.float64]),
    grid_cells=st.sampled_from([4_000_000, 1]),
)
def test_the_points_near_the_object_are_those_every_query_finds(
    seed, size, voxel, stray, dtype, grid_cells
):
    """Points sharing a cell with the object's need no query: the same points, the same result."""
    from mvbb_ros.pipeline import density

    rng = np.random.default_rng(seed)
    shape = rng.uniform(0.3, 1.0, 3) * size
    raw = box_surface(tuple(shape), voxel / 4.0, seed % 1000)
    # Stray points in and around it (a neighbour's, noise): near the object and farther than
    # a voxel's diagonal from it (inside the box, well within its bounds).
    strays = rng.uniform(-0.2, 1.2, (stray, 3)) * shape + (0.0, 0.0, 0.6)
    raw = np.concatenate([raw, strays]).astype(dtype)
    observed, _ = filter_points(raw, voxel_size=voxel, outlier_neighbors=8)
    captured = {}

    def capture(points, **options):
        captured['near'] = points
        return filter_points(points, **options)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(density, 'MAX_NEAR_CELLS', grid_cells)  # 1: every point queried
        patch.setattr(density, 'filter_points', capture)
        finer = density.finer_object_points(observed, raw, voxel, 80, 0.0005, 8, 2.0)
    assert 'near' in captured  # 80 voxels across: always finer
    assert finer is None or len(finer.points)
    expected = _reference_near(observed, raw, voxel)
    assert captured['near'].tobytes() == expected.tobytes()
