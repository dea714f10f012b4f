"""
Wrench-space quality of a set of contacts: the Ferrari-Canny epsilon and the hull volume V.

Each contact is a soft finger (Coulomb friction linearised by ``cone_edges`` edges, plus
torsional friction about the normal); torques are divided by the object's radius so the quality
has no units. The grasp wrench space is the convex hull of the contact wrenches; epsilon is the
distance from the origin to its nearest facet when the origin is inside, V its 6D volume
(definitions in ``docs/evaluation_protocol.md``).
"""

from __future__ import annotations

from mvbb_ros.arrays import BoolArray, cross, FloatArray
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

#: Default Coulomb friction coefficient: 0.5, a common value for rubber-padded fingers in
#: grasp-quality studies (a half-angle of 26.6 degrees).
DEFAULT_FRICTION = 0.5
#: Default number of friction cone edges of the linearised cone.
DEFAULT_CONE_EDGES = 8

_EPSILON_TOLERANCE = 1e-9
_RANK_TOLERANCE = 1e-9


def unit_rows(vectors: FloatArray) -> FloatArray:
    """Return the rows of `vectors` (..., 3) scaled to unit length (zero rows stay zero)."""
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 0.0)


def line_in_friction_cones(
    contacts: ArrayLike, normals: ArrayLike, friction: float = DEFAULT_FRICTION
) -> BoolArray:
    """
    Tell, per two-contact grasp, whether the line between the contacts is inside both cones.

    Nguyen's antipodal test: the segment from contact 0 to contact 1 makes an angle below
    ``atan(friction)`` with contact 0's inward normal, and the segment from 1 to 0 with contact
    1's (strictly, up to 1e-9 of the cosine). Coincident contacts fail.

    :param contacts: (..., 2, 3) the two contact points.
    :param normals: (..., 2, 3) their unit inward normals (the directions the fingers push).
    :param friction: Coulomb coefficient mu (>= 0).
    :return: (...) booleans.
    """
    points = np.asarray(contacts, dtype=np.float64)
    inward = np.asarray(normals, dtype=np.float64)
    line = points[..., 1, :] - points[..., 0, :]
    length = np.linalg.norm(line, axis=-1)
    unit = np.divide(
        line, length[..., None], out=np.zeros_like(line), where=length[..., None] > 0.0
    )
    limit = np.cos(np.arctan(friction)) - 1e-9
    first = np.einsum('...i,...i->...', inward[..., 0, :], unit)
    second = -np.einsum('...i,...i->...', inward[..., 1, :], unit)
    return (length > 0.0) & (first > limit) & (second > limit)


def _tangents(normals: FloatArray, references: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return unit tangents t1 (reference projected off the normal), t2 = n x t1."""
    t1 = references - np.einsum('...i,...i->...', references, normals)[..., None] * normals
    weak = np.linalg.norm(t1, axis=-1) < 1e-6
    if np.any(weak):
        # Reference (nearly) along the normal: any perpendicular will do, chosen stably.
        n = normals[weak]
        helper = np.where(
            (np.abs(n[:, 0]) < 0.9)[:, None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
        )
        t1[weak] = helper - np.einsum('ij,ij->i', helper, n)[:, None] * n
    t1 = unit_rows(t1)
    return t1, cross(normals, t1)


def contact_wrenches(
    points: ArrayLike,
    normals: ArrayLike,
    *,
    center: ArrayLike,
    scale: float,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    torsion: float = 0.0,
    references: ArrayLike | None = None,
) -> FloatArray:
    """
    Return the primitive wrenches of contacts, any leading shape (``docs/evaluation_protocol.md``).

    :param points: (..., K, 3) contact points.
    :param normals: (..., K, 3) unit inward normals (the direction each finger pushes).
    :param center: (3,) torque origin, the centre of mass.
    :param scale: torque scale rho (> 0), torques are divided by it.
    :param friction: Coulomb coefficient mu (>= 0).
    :param cone_edges: edges of the linearised friction cone (>= 3).
    :param torsion: torsional friction gamma, moment per unit normal force (mesh units, >= 0);
        0 for hard point contacts.
    :param references: (..., K, 3) directions whose projections orient the cone edges (default
        the direction from each contact to the centre, so the result turns with the contacts).
    :return: (..., K * (cone_edges + 2), 6) wrenches, or (..., K * cone_edges, 6) when
        ``torsion`` is 0; force first, then torque / rho.
    """
    if cone_edges < 3:
        raise ValueError(f'cone_edges must be >= 3, got {cone_edges}')
    if not friction >= 0.0 or not torsion >= 0.0 or not scale > 0.0:
        raise ValueError('friction and torsion must be >= 0 and scale > 0')
    pts = np.asarray(points, dtype=np.float64)
    nrm = unit_rows(np.asarray(normals, dtype=np.float64))
    centre = np.asarray(center, dtype=np.float64).reshape(3)
    refs = centre - pts if references is None else np.asarray(references, dtype=np.float64)
    refs = np.broadcast_to(refs, pts.shape).copy()
    t1, t2 = _tangents(nrm, refs)
    angles = 2.0 * np.pi * np.arange(cone_edges) / cone_edges
    forces = nrm[..., None, :] + friction * (
        np.cos(angles)[:, None] * t1[..., None, :] + np.sin(angles)[:, None] * t2[..., None, :]
    )  # (..., K, m, 3)
    arms = (pts - centre) / scale
    torques = cross(arms[..., None, :], forces)
    parts = [np.concatenate([forces, torques], axis=-1)]
    if torsion > 0.0:
        base = cross(arms, nrm)
        twist = (torsion / scale) * nrm
        for sign in (1.0, -1.0):
            parts.append(np.concatenate([nrm, base + sign * twist], axis=-1)[..., None, :])
    wrenches = np.concatenate(parts, axis=-2)  # (..., K, m(+2), 6)
    return wrenches.reshape(*wrenches.shape[:-3], -1, 6)


def wrench_space_quality(wrenches: ArrayLike) -> tuple[float, float]:
    """
    Return (epsilon, volume) of the convex hull of 6D wrenches.

    epsilon is the distance from the origin to the nearest facet when the origin is strictly
    inside, else 0; volume is the hull's 6D volume. Both are 0 when the wrenches do not span 6D
    or Qhull fails even with joggled input.

    :param wrenches: (W, 6) wrenches.
    :return: ``(epsilon, volume)``.
    """
    points = np.asarray(wrenches, dtype=np.float64).reshape(-1, 6)
    if len(points) < 7 or not np.all(np.isfinite(points)):
        return 0.0, 0.0
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if not spread[0] > 0.0 or spread[5] <= _RANK_TOLERANCE * spread[0]:
        return 0.0, 0.0
    hull = None
    for options in (None, 'QJ'):
        try:
            hull = ConvexHull(points, qhull_options=options)
            break
        except (QhullError, ValueError):
            continue
    if hull is None:
        return 0.0, 0.0
    margin = -float(hull.equations[:, -1].max())
    epsilon = margin if margin > _EPSILON_TOLERANCE else 0.0
    return epsilon, float(hull.volume)


def contact_quality(
    points: ArrayLike,
    normals: ArrayLike,
    *,
    center: ArrayLike,
    scale: float,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    torsion: float = 0.0,
    references: ArrayLike | None = None,
) -> tuple[float, float]:
    """
    Return (epsilon, volume) of a set of contacts.

    :func:`contact_wrenches` then :func:`wrench_space_quality`.

    :param points: (K, 3) contact points.
    :param normals: (K, 3) inward normals.
    :param center: (3,) torque origin.
    :param scale: torque scale rho.
    :param friction: Coulomb coefficient.
    :param cone_edges: friction cone edges.
    :param torsion: torsional friction (0: hard contacts).
    :param references: cone orientation references (see :func:`contact_wrenches`).
    :return: ``(epsilon, volume)``.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return 0.0, 0.0
    wrenches = contact_wrenches(
        pts,
        np.asarray(normals, dtype=np.float64).reshape(-1, 3),
        center=center,
        scale=scale,
        friction=friction,
        cone_edges=cone_edges,
        torsion=torsion,
        references=None if references is None else np.asarray(references, float).reshape(-1, 3),
    )
    return wrench_space_quality(wrenches)
