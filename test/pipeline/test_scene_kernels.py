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
