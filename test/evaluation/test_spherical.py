"""The paper's spherical baseline (evaluation.spherical): its grasps and the expected best of k."""

from __future__ import annotations

from mvbb_ros.evaluation.spherical import expected_best_of, spherical_grasps
import numpy as np
import pytest


def test_spherical_grasps_match_the_paper_count_and_geometry():
    centre = np.array([1.0, 2.0, 3.0])
    sphere = spherical_grasps(centre, 2.0, 10)
    assert len(sphere) == 22104  # the paper's count
    offsets = sphere.positions - centre
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), 2.0)
    np.testing.assert_allclose(sphere.approaches, -offsets / 2.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sphere.closings, axis=1), 1.0)
    np.testing.assert_allclose(
        np.einsum('ij,ij->i', sphere.closings, sphere.approaches), 0, atol=1e-12
    )
    poses = np.round(np.hstack([sphere.positions, sphere.closings]), 9)
    assert len(np.unique(poses, axis=0)) == len(sphere)
    assert len(spherical_grasps(centre, 1.0, 20)) == 2 * 18 + 8 * 18 * 18
    with pytest.raises(ValueError, match='divide 180'):
        spherical_grasps(centre, 1.0, 7)


def test_expected_best_of_matches_simulation():
    rng = np.random.default_rng(0)
    values = rng.random(40)
    simulated = np.mean([rng.choice(values, 5, replace=False).max() for _ in range(20000)])
    assert expected_best_of(values, 5) == pytest.approx(simulated, abs=5e-3)
    assert expected_best_of(values, 1) == pytest.approx(values.mean())
    assert expected_best_of(values, 40) == pytest.approx(values.max())
    assert expected_best_of([], 3) == 0.0
