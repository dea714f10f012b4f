"""
The scene stage's compiled kernels against the numpy and scipy code they replace, float for float.

Apart from ``test_scene.py`` (which needs Open3D's depth camera for its frames), so that
``make compat`` runs them on Ubuntu 24.04's numba, numpy and scipy too.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st
from mvbb_ros.arrays import cross
from mvbb_ros.pipeline import outline, plane
import numpy as np
from scipy.spatial import ConvexHull, QhullError


@hypothesis_settings(max_examples=60, deadline=None)
@given(
    count=st.integers(1, 700),
    planes=st.integers(1, 300),
    share=st.floats(0.0, 1.0),
    block=st.sampled_from([1, 7, 64, 128]),
    seed=st.integers(0, 10_000),
)
def test_property_best_plane_is_the_argmax_of_every_count(count, planes, share, block, seed):
    """`_best_plane` (preemptive guess, then counts cut short) names ``argmax`` of all counts."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (count, 3))
    points[: int(share * count), 2] = rng.normal(0.0, 0.01, int(share * count))  # a plane
    # Coarse normals and offsets: many planes tie (the first must win).
    normals = rng.normal(0.0, 1.0, (planes, 3)) * [0.2, 0.2, 1.0]
    normals = np.round(normals / np.linalg.norm(normals, axis=1, keepdims=True), 1)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    offsets = np.round(rng.normal(0.0, 0.05, planes), 2)
    # The same float operations as the kernel: a x + b y + c z + d, one at a time.
    x, y, z = (points[:, k][None] for k in range(3))
    a, b, c = (normals[:, k][:, None] for k in range(3))
    counts = np.count_nonzero(np.abs(a * x + b * y + c * z + offsets[:, None]) <= 0.02, axis=1)
    columns = np.ascontiguousarray(points.T)
    assert plane._best_plane(columns, normals, offsets, 0.02, block) == np.argmax(counts)


def _numpy_plane(points):
    """Return the least-squares plane as numpy computes it: centroid, scatter, ``eigh``."""
    points = points[:: max(1, len(points) // plane.REFIT_POINTS)]
    center = points.mean(axis=0)
    centred = points - center
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, 0], -float(vectors[:, 0] @ center)


def _same_plane(first, second, tolerance):
    """Tell whether two (normal, offset) are one plane (either orientation)."""
    sign = 1.0 if float(first[0] @ second[0]) >= 0.0 else -1.0
    return (
        np.allclose(first[0], sign * second[0], atol=tolerance)
        and abs(first[1] - sign * second[1]) <= tolerance
    )


@hypothesis_settings(max_examples=100, deadline=None)
@given(
    count=st.integers(3, 40_000),
    tilt=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.1, 1.0)),
    noise=st.sampled_from([0.0, 1e-4, 3e-3]),
    spread=st.floats(0.01, 10.0),
    seed=st.integers(0, 10_000),
)
def test_property_least_squares_plane_is_numpys(count, tilt, noise, spread, seed):
    """`plane_through` (the compiled centroid, scatter and eigh) is numpy's plane to rounding."""
    rng = np.random.default_rng(seed)
    normal = np.asarray(tilt) / np.linalg.norm(tilt)
    flat = rng.uniform(-spread, spread, (count, 2))
    first = cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = cross(normal, first)
    points = (
        flat[:, :1] * first + flat[:, 1:] * second + rng.normal(0.0, noise, (count, 1)) * normal
    )
    points += rng.uniform(-3.0, 3.0, 3)
    fitted = plane.plane_through(points)
    assert abs(np.linalg.norm(fitted[0]) - 1.0) < 1e-12
    assert _same_plane(fitted, _numpy_plane(points), 1e-9 * max(1.0, spread))
    if noise == 0.0 and count >= 3 and np.linalg.matrix_rank(flat - flat.mean(0), 1e-9) == 2:
        assert _same_plane(fitted, (normal, -float(normal @ points[0])), 1e-9 * spread)


@hypothesis_settings(max_examples=60, deadline=None)
@given(
    count=st.integers(3, 5000),
    share=st.floats(0.2, 1.0),
    slant=st.floats(0.0, 0.3),
    rounds=st.integers(1, 5),
    seed=st.integers(0, 10_000),
)
def test_property_refit_is_the_rounds_of_numpy_fits(count, share, slant, rounds, seed):
    """`_refit` takes the same rounds as numpy fits on each round's inliers, to rounding."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (count, 3))
    table = int(share * count)
    points[:table, 2] = rng.normal(0.0, 0.003, table)  # a table, and clutter above and below it
    start = np.array([slant, 0.0, 1.0]) / np.linalg.norm([slant, 0.0, 1.0])
    settled = np.cos(np.radians(plane.REFIT_TURN_DEG))
    normal, offset = start, 0.0
    for _ in range(rounds):  # the reference: the loop the kernel replaces
        near = np.abs(points @ normal + offset) <= 0.01
        if np.count_nonzero(near) < 3:
            break
        previous = normal
        normal, offset = _numpy_plane(points[near])
        if abs(float(normal @ previous)) >= settled:
            break
    fitted = plane._refit(points, start.copy(), 0.0, 0.01, rounds, settled)
    assert _same_plane(fitted, (normal, offset), 1e-9)


@hypothesis_settings(max_examples=150, deadline=None)
@given(
    count=st.integers(3, 3000),
    shape=st.sampled_from(['box', 'disc', 'normal', 'lattice', 'line']),
    turn=st.floats(0.0, 6.3),
    shift=st.tuples(st.floats(-5.0, 5.0), st.floats(-5.0, 5.0)),
    seed=st.integers(0, 10_000),
)
def test_property_the_octagon_cull_keeps_the_outline(count, shape, turn, shift, seed):
    """`outline_2d` (Qhull on the points off the octagon) is Qhull's outline of all points."""
    rng = np.random.default_rng(seed)
    if shape == 'box':
        flat = rng.uniform(-1.0, 1.0, (count, 2)) * [1.0, 0.3]
    elif shape == 'disc':
        angle, radius = rng.uniform(0.0, 2 * np.pi, count), np.sqrt(rng.uniform(0, 1, count))
        flat = np.column_stack([np.cos(angle), np.sin(angle)]) * radius[:, None]
    elif shape == 'normal':
        flat = rng.normal(0.0, 1.0, (count, 2))
    elif shape == 'lattice':  # many collinear points on the hull
        flat = np.round(rng.uniform(-1.0, 1.0, (count, 2)) * 10.0) / 10.0
    else:  # degenerate: Qhull fails, no outline
        flat = np.outer(rng.uniform(-1.0, 1.0, count), [1.0, 2.0])
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    flat = flat @ rotation.T + shift
    try:
        expected = flat[ConvexHull(flat).vertices]
    except QhullError:
        expected = np.empty((0, 2))
    np.testing.assert_array_equal(outline.outline_2d(flat), expected)


def _largest_patch_numpy(flat: np.ndarray, cell: float) -> np.ndarray:
    """Return the patch as numpy and scipy find it (what the compiled cells must reproduce)."""
    from scipy import ndimage

    cells = ((flat - flat.min(axis=0)) / cell).astype(np.int64)
    occupied = np.zeros(tuple(int(v) + 1 for v in cells.max(axis=0)), dtype=bool)
    occupied[cells[:, 0], cells[:, 1]] = True
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    point_labels = labels[cells[:, 0], cells[:, 1]]
    sizes = np.bincount(point_labels)
    sizes[0] = 0
    return np.flatnonzero(point_labels == int(np.argmax(sizes)))


@hypothesis_settings(max_examples=150, deadline=None)
@given(
    count=st.integers(1, 2000),
    patches=st.integers(1, 6),
    cell=st.sampled_from([0.01, 0.02, 0.05, 0.3]),
    seed=st.integers(0, 10_000),
)
def test_property_the_largest_patch_is_numpys(count, patches, cell, seed):
    """`largest_patch` (compiled cells and counts) keeps the points numpy's version keeps."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1.0, 1.0, (patches, 2))
    flat = centres[rng.integers(0, patches, count)] + rng.normal(0.0, 0.08, (count, 2))
    flat = np.round(flat, 2)  # points on cell edges
    np.testing.assert_array_equal(
        outline.largest_patch(flat, cell), _largest_patch_numpy(flat, cell)
    )


@hypothesis_settings(max_examples=100, deadline=None)
@given(
    count=st.integers(1, 300),
    planes=st.integers(1, 200),
    scale=st.sampled_from([1e-3, 1.0, 50.0]),
    seed=st.integers(0, 10_000),
)
def test_property_triple_normals_are_numpys(count, planes, scale, seed):
    """The compiled triangle normals and lengths are numpy's floats (the cross, the norm)."""
    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, scale, (count, 3))
    corners = rng.integers(0, count, (planes, 3))
    triples = points[corners]
    expected = cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    normals, lengths = plane._triple_normals(points, corners)
    np.testing.assert_array_equal(normals, expected)
    np.testing.assert_array_equal(lengths, np.linalg.norm(expected, axis=1))
