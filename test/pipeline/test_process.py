"""The pipeline's fast decoder (read_points) and process_cloud with both voxel back-ends."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline.decode import CloudFormatError, read_points, read_xyz
from mvbb_ros.pipeline.process import (
    decode_cloud,
    implausible_extent,
    process_cloud,
    process_points,
)
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
import pytest

CODES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}


def raw_cloud(
    grid: np.ndarray,
    datatypes: tuple[int, int, int],
    offsets: tuple[int, int, int],
    point_step: int,
    row_padding: int = 0,
    is_bigendian: bool = False,
) -> SimpleNamespace:
    """Encode an (H, W, 3) grid with any field types, offsets, padding and byte order."""
    height, width, _ = grid.shape
    order = '>' if is_bigendian else '<'
    row_step = width * point_step + row_padding
    data = np.zeros(height * row_step, dtype=np.uint8)
    view = np.ndarray(
        (height, width),
        dtype=np.dtype(
            {
                'names': list('xyz'),
                'formats': [order + CODES[datatype] for datatype in datatypes],
                'offsets': list(offsets),
                'itemsize': point_step,
            }
        ),
        buffer=data,
        strides=(row_step, point_step),
    )
    for axis, name in enumerate('xyz'):
        view[name] = grid[:, :, axis]
    fields = [
        SimpleNamespace(name=name, offset=offset, datatype=datatype, count=1)
        for name, offset, datatype in zip('xyz', offsets, datatypes, strict=True)
    ]
    return SimpleNamespace(
        header=SimpleNamespace(frame_id='f', stamp=SimpleNamespace(sec=0, nanosec=0)),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=is_bigendian,
        point_step=point_step,
        row_step=row_step,
        data=data.tobytes(),
        is_dense=False,
    )


def holed_grid(shape: tuple[int, int], seed: int = 0, fraction: float = 0.3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    grid = rng.normal(size=(*shape, 3)).astype(np.float32)
    holes = rng.random(grid.shape) < fraction / 3
    grid[holes] = rng.choice(np.array([np.nan, np.inf, -np.inf], dtype=np.float32), holes.sum())
    return grid


LAYOUTS = {
    'packed float32': ((7, 7, 7), (0, 4, 8), 12, 0),
    'PCL padding 16': ((7, 7, 7), (0, 4, 8), 16, 0),
    'xyz after rgb': ((7, 7, 7), (4, 8, 12), 20, 0),
    'row padding': ((7, 7, 7), (0, 4, 8), 16, 12),
    'float64': ((8, 8, 8), (0, 8, 16), 24, 0),
    'z before x': ((7, 7, 7), (8, 4, 0), 12, 0),
    'gap between y and z': ((7, 7, 7), (0, 4, 12), 16, 0),
    'mixed float32 float64': ((7, 8, 7), (0, 4, 12), 16, 0),
    'int16 coordinates': ((3, 3, 3), (0, 2, 4), 8, 0),
}


@pytest.mark.parametrize('bigendian', [False, True])
@pytest.mark.parametrize('name', list(LAYOUTS))
def test_read_points_equals_read_xyz(name, bigendian):
    datatypes, offsets, point_step, row_padding = LAYOUTS[name]
    grid = holed_grid((5, 7))
    if datatypes[0] == 3:
        grid = np.nan_to_num(grid * 100, nan=0, posinf=0, neginf=0).round()
    cloud = raw_cloud(grid, datatypes, offsets, point_step, row_padding, bigendian)
    before = bytes(cloud.data)

    points = read_points(cloud)

    np.testing.assert_array_equal(points, read_xyz(cloud))
    expected = np.float32 if datatypes == (7, 7, 7) else np.float64
    assert points.dtype == expected
    assert points.flags.c_contiguous and points.flags.writeable
    assert not np.shares_memory(points, np.frombuffer(cloud.data, dtype=np.uint8))
    assert bytes(cloud.data) == before


def test_read_points_on_rclpy_messages_and_empty_clouds():
    grid = holed_grid((30, 40), seed=1)
    cloud = create_cloud_xyz(grid.reshape(-1, 3), organized_shape=grid.shape[:2])
    np.testing.assert_array_equal(read_points(cloud), read_xyz(cloud))
    assert decode_cloud(cloud).points.dtype == np.float32
    empty = create_cloud_xyz(np.empty((0, 3)))
    assert read_points(empty).shape == (0, 3)
    assert read_points(raw_cloud(np.empty((0, 4, 3)), (8, 8, 8), (0, 8, 16), 24)).dtype == (
        np.float64
    )


def test_read_points_rejects_what_read_xyz_rejects():
    cloud = raw_cloud(holed_grid((2, 3)), (7, 7, 7), (0, 4, 8), 16)
    short = SimpleNamespace(**{**vars(cloud), 'data': cloud.data[:-1]})
    no_z = SimpleNamespace(**{**vars(cloud), 'fields': cloud.fields[:2]})
    for broken, pattern in ((short, 'data has'), (no_z, 'no field')):
        with pytest.raises(CloudFormatError, match=pattern):
            read_xyz(broken)
        with pytest.raises(CloudFormatError, match=pattern):
            read_points(broken)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(list(LAYOUTS)),
    st.booleans(),
    st.integers(0, 4),
    st.integers(1, 9),
    st.sampled_from([0.0, 0.5, 1.0]),
    st.integers(0, 2**16),
)
def test_property_read_points_equals_read_xyz(name, bigendian, height, width, holes, seed):
    datatypes, offsets, point_step, row_padding = LAYOUTS[name]
    grid = holed_grid((height, width), seed=seed, fraction=holes)
    if datatypes[0] == 3:
        grid = np.nan_to_num(grid * 100, nan=0, posinf=0, neginf=0).round()
    cloud = raw_cloud(grid, datatypes, offsets, point_step, row_padding, bigendian)
    points = read_points(cloud)
    np.testing.assert_array_equal(points, read_xyz(cloud))
    assert points.shape[1] == 3 and np.isfinite(points).all()


def l_shape(count: int = 40_000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    arm = rng.uniform((0.0, 0.0, 0.0), (0.20, 0.04, 0.04), size=(count // 2, 3))
    leg = rng.uniform((0.0, 0.0, 0.0), (0.04, 0.16, 0.04), size=(count - count // 2, 3))
    points = np.concatenate([arm, leg]) + (0.0, 0.0, 0.8)
    return points.astype(np.float32)


def test_the_crop_while_decoding_gives_what_the_filters_give_on_points():
    points = l_shape()
    cloud = create_cloud_xyz(points, frame_id='camera')
    settings = PipelineSettings().updated(
        {'crop_min': [0.0, 0.0, 0.0], 'crop_max': [0.15, 1.0, 1.0]}
    )
    decoded = process_cloud(cloud, settings)
    plain = process_points(points, settings)

    assert decoded.warning is None and plain.warning is None
    assert decoded.counts == plain.counts
    assert decoded.counts.finite == len(points) > decoded.counts.cropped
    assert len(decoded.leaves) == len(plain.leaves) == 2
    for mine, other in zip(decoded.leaves, plain.leaves, strict=True):
        assert mine.volume == other.volume
        np.testing.assert_array_equal(mine.center, other.center)
    assert set(decoded.timings_ms) == {
        'decode',
        'filter',
        'scene',
        'objects',
        'completion',
        'decompose',
        'grasps',
        'refine',
    }


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
def test_points_without_a_crop_box_give_what_an_open_crop_and_a_decoded_cloud_give(dtype):
    """process_points reuses the corners of its extent check as the voxel grid's bounds."""
    points = l_shape().astype(dtype)
    settings = PipelineSettings()
    plain = process_points(points, settings)
    low, high = points.min(axis=0) - 1.0, points.max(axis=0) + 1.0
    opened = {'crop_min': low.tolist(), 'crop_max': high.tolist()}
    cropped = process_points(points, settings.updated(opened))
    decoded = process_cloud(create_cloud_xyz(points, frame_id='camera'), settings)

    assert plain.warning is None
    assert plain.counts == cropped.counts
    assert plain.counts.finite == plain.counts.cropped == len(points)
    others = [cropped, decoded] if dtype == np.float32 else [cropped]  # the decoder: float32
    for other in others:
        assert len(other.leaves) == len(plain.leaves) >= 1
        for mine, theirs in zip(plain.leaves, other.leaves, strict=True):
            assert mine.volume == theirs.volume
            np.testing.assert_array_equal(mine.center, theirs.center)


def test_the_voxel_backend_setting_is_gone_and_says_why():
    with pytest.raises(ValueError, match="voxel_backend was replaced by nothing.*Open3D's"):
        PipelineSettings().updated({'voxel_backend': 'numpy'})


def test_an_absurd_float32_cloud_is_refused_with_its_finite_span():
    """Random bytes reach +-3.4e38 in float32: the reason gives the span, not inf."""
    points = np.array([[3.4e38, 0.0, 0.1], [-3.4e38, 0.2, 0.3]], dtype=np.float32)
    reason = implausible_extent(points)
    assert reason is not None and '6.8e+38 x 0.2 x 0.2 m' in reason, reason
    assert implausible_extent(points[:, [1, 2, 1]] * np.float32(10.0)) is None


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
@pytest.mark.parametrize(('voxel_size', 'outlier_neighbors'), [(0.0, 0), (0.0, 20), (0.005, 0)])
def test_any_filter_switched_off_still_processes_read_only_clouds(
    dtype, voxel_size, outlier_neighbors
):
    """Both filters off hand the caller's (read-only) array straight to the compiled stages."""
    from dataclasses import replace

    rng = np.random.default_rng(4)
    box = rng.uniform((-0.03, -0.02, 0.5), (0.03, 0.02, 0.56), size=(2000, 3)).astype(dtype)
    box.setflags(write=False)
    before = box.copy()
    node = PipelineSettings()
    settings = replace(
        node,
        filtering=replace(
            node.filtering, voxel_size=voxel_size, outlier_neighbors=outlier_neighbors
        ),
    )
    result = process_points(box, settings)
    assert result.warning is None
    assert result.objects and result.objects[0].decomposition.leaves
    np.testing.assert_array_equal(box, before)


def test_max_objects_keeps_the_largest_objects_of_a_frame_and_says_what_it_left_out():
    from dataclasses import replace

    rng = np.random.default_rng(5)
    sizes = np.arange(40, 40 + 12 * 15, 15)  # twelve blobs, each larger than the last
    centres = np.column_stack([np.arange(12) * 0.2, np.zeros(12), np.full(12, 0.8)])
    blobs = [c + rng.normal(scale=0.01, size=(n, 3)) for c, n in zip(centres, sizes, strict=True)]
    cloud = np.concatenate(blobs)
    node = PipelineSettings()
    settings = replace(
        node,
        view=replace(node.view, max_objects=5, completion='none'),
        filtering=replace(node.filtering, voxel_size=0.0, outlier_neighbors=0),
    )
    capped = process_points(cloud, settings)
    everything = process_points(
        cloud, replace(settings, view=replace(settings.view, max_objects=0))
    )
    assert len(everything.objects) == 12 and not everything.capped
    counts = [len(item.point_indices) for item in everything.objects]
    assert counts == sorted(counts, reverse=True)
    assert [len(item.point_indices) for item in capped.objects] == counts[:5]
    assert capped.capped == [
        f'max_objects: kept the 5 largest of 12 objects ({sum(counts[5:])} points left out)'
    ]
    assert capped.capped[0] in capped.notes
