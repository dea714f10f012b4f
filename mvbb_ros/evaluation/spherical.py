"""
The paper's baseline: grasps from a sphere around the object, aimed at its centre of mass.

Polar angle, azimuth and roll in steps of ``step_deg`` (10 degrees: the paper's 22104 grasps);
:func:`expected_best_of` gives what as many random spherical grasps as a box set has would reach.
See ``docs/evaluation_protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from mvbb_ros.arrays import cross, FloatArray
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import gammaln

#: Default angular step of the spherical baseline, degrees (the paper's).
DEFAULT_SPHERICAL_STEP_DEG = 10.0


@dataclass(frozen=True)
class SphericalGrasps:
    """
    The paper's spherical grasps, arrays of equal length G.

    :ivar positions: (G, 3) TCP positions on the sphere.
    :ivar approaches: (G, 3) unit approach directions, towards the centre.
    :ivar closings: (G, 3) unit closing directions, perpendicular to the approaches.
    :ivar angles_deg: (G, 3) polar angle, azimuth and roll, degrees.
    """

    positions: FloatArray
    approaches: FloatArray
    closings: FloatArray
    angles_deg: FloatArray

    def __len__(self) -> int:
        return len(self.positions)

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return ``(positions, approaches, closings)``, as the simulation takes them."""
        return self.positions, self.approaches, self.closings


def spherical_grasps(
    center: ArrayLike, radius: float, step_deg: float = DEFAULT_SPHERICAL_STEP_DEG
) -> SphericalGrasps:
    """
    Return grasps from a sphere, approaching its centre (the paper's baseline).

    Polar angle theta in 0, step, ..., 180 degrees; azimuth phi and roll psi in 0, step, ...,
    360 - step. At the poles only psi varies. The TCP is at ``center + radius * u`` with
    ``u = (sin theta cos phi, sin theta sin phi, cos theta)``, the approach is ``-u`` and the
    closing direction is ``e_theta = d u / d theta`` turned by psi about the approach.

    :param center: (3,) the sphere's centre (the object's centre of mass).
    :param radius: the sphere's radius (> 0); put the hand outside the object.
    :param step_deg: angular step in degrees; 180 must be a whole multiple of it.
    :return: the grasps (22104 for 10 degrees).
    :raises ValueError: for a step that does not divide 180 or a bad radius.
    """
    steps = 180.0 / step_deg if step_deg > 0 else 0.0
    if not step_deg > 0 or abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
        raise ValueError(f'step_deg must divide 180 degrees, got {step_deg}')
    if not radius > 0.0:
        raise ValueError(f'radius must be > 0, got {radius}')
    half_turn = round(steps)
    polar = np.arange(half_turn + 1) * step_deg
    around = np.arange(2 * half_turn) * step_deg
    rows = []
    for theta in polar:
        azimuths = around[:1] if theta in (0.0, 180.0) else around
        grid = np.array(np.meshgrid(azimuths, around, indexing='ij')).reshape(2, -1).T
        rows.append(np.column_stack([np.full(len(grid), theta), grid]))
    angles = np.concatenate(rows)
    theta, phi, psi = np.deg2rad(angles).T
    u = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    e_theta = np.column_stack(
        [np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), -np.sin(theta)]
    )
    approach = -u
    turned = cross(approach, e_theta)
    closing = np.cos(psi)[:, None] * e_theta + np.sin(psi)[:, None] * turned
    centre = np.asarray(center, dtype=np.float64).reshape(3)
    return SphericalGrasps(
        positions=centre + radius * u,
        approaches=approach,
        closings=closing,
        angles_deg=angles,
    )


def expected_best_of(values: ArrayLike, count: int) -> float:
    """
    Return the expected largest of `count` values drawn at random, without replacement.

    The same-budget baseline: what `count` random spherical grasps would find on average.
    With the values sorted ascending, the k-th is the largest drawn with probability
    ``C(k - 1, count - 1) / C(N, count)``.

    :param values: (N,) values.
    :param count: draws, 1 <= count (clipped to N).
    :return: the expected maximum (0 for no values).
    """
    ordered = np.sort(np.asarray(values, dtype=np.float64).reshape(-1))
    total = len(ordered)
    if total == 0 or count < 1:
        return 0.0
    draws = min(int(count), total)
    ranks = np.arange(1, total + 1)
    usable = ranks >= draws
    log_weights = np.full(total, -np.inf)
    k = ranks[usable]
    log_weights[usable] = _log_choose(k - 1, draws - 1) - _log_choose(np.array([total]), draws)[0]
    return float(np.sum(np.exp(log_weights) * ordered))


def _log_choose(n: NDArray[np.int64], k: int) -> FloatArray:
    n = np.asarray(n, dtype=np.float64)
    return gammaln(n + 1) - gammaln(k + 1) - gammaln(n - k + 1)
