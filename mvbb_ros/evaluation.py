"""
Wrench-space grasp quality of a parallel-jaw gripper on a triangle mesh (no ROS import).

Huebner, Ruthotto and Kragic (ICRA 2008), Section IV-B and Figure 6, simulate box-face grasp
hypotheses in GraspIt! and score each with two wrench-space measures, the Ferrari-Canny epsilon
and the hull volume V, against a baseline of "spherical" grasps. This module is our own small
simulator of that experiment: a parallel-jaw gripper on Open3D ray casting
(:class:`open3d.t.geometry.RaycastingScene`) and scipy's Qhull. Everything is written here from
the textbook definitions; nothing is taken from GraspIt! or other grasp libraries.

Units are those of the mesh. Every quality is unit-free: forces have unit normal component and
torques are divided by the object's radius, so a model in millimetres and the same model in
metres score the same when the gripper is scaled with them
(:meth:`ParallelJawGripper.for_object` does that).

Gripper
-------
A grasp is a pre-grasp pose: ``position`` (the TCP, the point between the two fingertips, as in
:mod:`mvbb_ros.geometry.grasps`), a unit ``approach`` direction (the way the hand moves) and a unit
``closing`` direction (the line the fingers close along; made orthogonal to ``approach``).
With ``side = approach x closing``, the hand (:class:`ParallelJawGripper`) is:

* two fingers, thin plates at ``+-max_width / 2`` along ``closing``, ``finger_width`` wide along
  ``side`` and ``finger_depth`` long along ``approach``; the fingertips are at the TCP's depth;
* a palm, the rectangle ``max_width`` by ``finger_width`` that joins the finger roots,
  ``finger_depth`` behind the fingertips.

The gripper always opens to ``max_width`` (it knows nothing about the object, the same for box
and spherical grasps).

Approach, retreat, close
------------------------
As in the paper ("approach along the normal until a contact is detected ... retreats a small
distance ... closes the fingers"), each grasp is simulated in three ray-casting steps, every
step for all grasps in one :meth:`~open3d.t.geometry.RaycastingScene.cast_rays` call:

1. **Approach.** Rays along ``approach`` from a grid on the palm (``palm_rays`` across the
   opening by ``width_rays`` across the finger width) give the travel ``h`` at which the palm
   would first touch the object. No palm ray hits: the object is not in the hand's path, status
   ``'missed'``. The hand stops at ``travel = h - retreat``.
2. **Collision.** Rays along ``approach`` from each fingertip (``width_rays`` across the finger
   width) give how far each finger can move. A finger that would touch the object before the
   hand stops (hit distance < ``travel``) collides with it while approaching, status
   ``'collision'``: the paper's hand would have stopped on its fingertip, and a parallel gripper
   cannot close around a surface its finger is pressing on.
3. **Close.** The contact line is at half the finger depth, ``travel - finger_depth / 2`` along
   ``approach`` from the start: the pad centres. One ray per finger, from its open position
   ``+-max_width / 2`` along ``closing`` inwards along ``-+closing``, finds its contact point
   (each finger moves until it touches, like a self-centring gripper). A ray that misses (or
   reaches the other finger) leaves that finger without contact, status ``'no_contact'``.
   Otherwise the status is ``'grasped'``; the two contacts are at most ``max_width`` apart by
   construction.

Simplifications, on purpose: each finger touches the object at one point (its pad centre line);
fingers and palm are sampled by rays (spacing ``max_width / (palm_rays - 1)`` and
``finger_width / (width_rays - 1)``), so a feature thinner than that can slip between rays;
the object does not move while the fingers close.

Contacts and wrenches
---------------------
A contact's normal is the normal of the triangle the ray hit (found by its primitive id, in
float64), oriented along the ray: it points into the object, the direction the finger pushes.
So the result does not depend on how the mesh's triangles are wound. Each contact is a soft
finger: Coulomb friction (coefficient ``friction``, mu) plus torsional friction about the
normal, linearised conservatively by ``cone_edges + 2`` unit-normal-force wrenches:

* the ``cone_edges`` (m) friction cone edges ``f_k = n + mu (cos a_k t1 + sin a_k t2)``,
  ``a_k = 2 pi k / m``, with torque ``(c - o) x f_k / rho`` and no torsion; ``t1`` is the
  component of the grasp's approach direction perpendicular to ``n`` (so the linearised cone
  turns with the grasp and the quality is invariant under rigid motions), ``t2 = n x t1``;
* the pure normal force ``n`` with torsion ``+-gamma n / rho`` added to its torque,
  ``gamma = (2 / 3) mu r``: the largest torsional moment per unit normal force of a disc of
  radius ``r = contact_radius`` under uniform pressure (default ``finger_width / 4``).

The convex hull of these points is inside the true soft-finger limit surface (tangential and
torsional friction trade off). ``contact_radius = 0`` gives hard point contacts: then two
contacts can never resist a torque about the line through them, and no two-finger grasp is
force-closure, which is why the default is a soft finger (real gripper pads are soft).
``o`` is the object's centre of mass and ``rho`` its radius, the largest distance from ``o`` to a
mesh vertex (GraspIt! scales torques by the object's maximum radius in the same way).

Centre of mass: when the mesh is closed (every edge shared by exactly two triangles with
opposite orientations) the centroid of the enclosed solid, from signed tetrahedra; otherwise the
area-weighted centroid of the surface. Open3D's ``is_watertight`` is not used because it also
rejects self-intersecting meshes (the GraspIt! mug's handle runs into its body); for those the
signed-tetrahedra centroid counts the overlap twice, a small error.

Quality
-------
The grasp wrench space is the convex hull (Qhull, in 6D) of all contact wrenches, the
Ferrari-Canny L1 construction (total normal force at most 1).

* ``epsilon``: the distance from the origin to the nearest hull facet when the origin is
  strictly inside the hull (force closure), else 0: the largest wrench, in every direction,
  that the grasp can resist with unit total normal force.
* ``volume``: the hull's 6D volume V (reported for every full-dimensional hull, force-closure
  or not).

Fewer than seven wrenches, or wrenches that do not span 6D (affine rank < 6, e.g. one contact,
or two hard contacts), give ``epsilon = volume = 0``; so does a Qhull failure that persists
with joggled input (``QJ``). ``force_closure`` is ``epsilon > 0``.

Speed: the hull is the expensive part (a few ms each). With ``closure_prefilter=True``
(:func:`evaluate_grasps`; the default of :func:`compare_grasp_sets`) grasps that Nguyen's
two-contact test proves not force-closure (the contact line outside a friction cone) skip it:
their epsilon is 0 as always and their V is NaN. On the shared models this cuts the 22104
spherical grasps from minutes to 5-20 s on one core, and leaves every epsilon unchanged.

Spherical grasps (the paper's baseline)
---------------------------------------
:func:`spherical_grasps`: TCPs on a sphere around the centre of mass, approach pointing at the
centre, two spherical angles (polar angle 0..180 degrees, azimuth 0..360) and a roll about the
approach, all in steps of ``step_deg``; at the poles the azimuth is redundant and only the
rolls vary. With 10 degrees that is 2 x 36 + 17 x 36 x 36 = 22104 grasps, exactly the paper's
count. (For a symmetric parallel gripper rolls 180 degrees apart are the same grasp with the
fingers swapped; they are kept so that the count matches the paper's asymmetric hand.)

Comparison (Figure 6)
---------------------
:func:`compare_grasp_sets` evaluates, on one object, the spherical grasps, the 24 grasps of
the root box (:func:`mvbb_ros.geometry.fit.minimum_bounding_box`) and the hypotheses of
decompositions (:func:`mvbb_ros.geometry.decomposition.decompose`) at several gain thresholds
(:func:`mvbb_ros.geometry.grasps.grasp_hypotheses`, ranked by its default strategy), all with
the same gripper; :func:`format_comparison` and :func:`plot_quality_space` turn it into the
table and the paper's (epsilon, V) scatter plot.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
import os
from pathlib import Path
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import ConvexHull, QhullError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Default Coulomb friction coefficient: 0.5, a common value for rubber-padded fingers in
#: grasp-quality studies (a half-angle of 26.6 degrees).
DEFAULT_FRICTION = 0.5
#: Default number of friction cone edges of the linearised cone.
DEFAULT_CONE_EDGES = 8
#: Default gripper opening and finger depth, as fractions of the object's diameter D.
DEFAULT_WIDTH_FACTOR = 1.2
DEFAULT_DEPTH_FACTOR = 0.5
#: Default angular step of the spherical baseline, degrees (the paper's).
DEFAULT_SPHERICAL_STEP_DEG = 10.0
#: Gain thresholds of the paper's decompositions (Table I, Fig. 5 and 6).
PAPER_THRESHOLDS: tuple[float, ...] = (0.90, 0.94, 0.98)
#: Outcome of a simulated grasp, :attr:`GraspEvaluation.status` indexes this tuple.
STATUS_NAMES: tuple[str, ...] = ('grasped', 'missed', 'collision', 'no_contact')
GRASPED, MISSED, COLLISION, NO_CONTACT = range(4)
#: The claim under test: the best box grasp reaches this fraction of the best spherical
#: epsilon ...
CLAIM_QUALITY_FRACTION = 0.90
#: ... with at most this fraction of the spherical grasps' count.
CLAIM_CANDIDATE_FRACTION = 0.01

_EPSILON_TOLERANCE = 1e-9
_RANK_TOLERANCE = 1e-9


# Mesh ------------------------------------------------------------------------------------------


def _edge_counts(triangles: NDArray[np.int64]) -> tuple[bool, bool]:
    """Return (every undirected edge in exactly two triangles, directed edges all distinct)."""
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    count = int(triangles.max()) + 1 if len(triangles) else 0
    undirected = np.sort(directed, axis=1)
    _, undirected_counts = np.unique(
        undirected[:, 0] * count + undirected[:, 1], return_counts=True
    )
    _, directed_counts = np.unique(directed[:, 0] * count + directed[:, 1], return_counts=True)
    return bool(np.all(undirected_counts == 2)), bool(np.all(directed_counts == 1))


def is_closed(triangles: ArrayLike) -> bool:
    """
    Return whether a triangle mesh is closed and consistently oriented.

    Closed means every edge is shared by exactly two triangles that traverse it in opposite
    directions, so the mesh bounds a solid and signed tetrahedra give its volume.

    :param triangles: (T, 3) vertex indices.
    :return: True for a closed, consistently oriented mesh.
    """
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(tris) < 4:
        return False
    two_per_edge, distinct = _edge_counts(tris)
    return two_per_edge and distinct


def center_of_mass(vertices: ArrayLike, triangles: ArrayLike) -> tuple[FloatArray, str]:
    """
    Return the centre of mass of a triangle mesh and how it was computed.

    A closed, consistently oriented mesh (:func:`is_closed`) with non-zero volume gives the
    centroid of the enclosed solid of uniform density (signed tetrahedra from the vertex mean);
    any other mesh gives the area-weighted centroid of its surface (a thin shell).

    :param vertices: (V, 3) vertex coordinates.
    :param triangles: (T, 3) vertex indices, T >= 1.
    :return: ``(centre, method)`` with method ``'solid'`` or ``'surface'``.
    :raises ValueError: when the mesh has no triangle of non-zero area.
    """
    verts = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if len(tris) == 0:
        raise ValueError('center_of_mass needs at least one triangle')
    origin = verts[np.unique(tris)].mean(axis=0)
    a, b, c = (verts[tris[:, k]] - origin for k in range(3))
    if is_closed(tris):
        six_volumes = np.einsum('ij,ij->i', a, np.cross(b, c))
        total = float(six_volumes.sum())
        scale = float(np.abs(six_volumes).sum())
        if scale > 0.0 and abs(total) > 1e-12 * scale:
            centre = (six_volumes[:, None] * (a + b + c)).sum(axis=0) / (4.0 * total)
            return origin + centre, 'solid'
    areas = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not areas.sum() > 0.0:
        raise ValueError('center_of_mass: every triangle has zero area')
    centre = (areas[:, None] * (a + b + c) / 3.0).sum(axis=0) / areas.sum()
    return origin + centre, 'surface'


_center_of_mass = center_of_mass  # GraspTarget's argument of that name hides the function


def _diameter(points: FloatArray) -> float:
    """Return the largest distance between two of `points` (over their convex hull)."""
    candidates = points
    if len(points) > 3:
        try:
            candidates = points[ConvexHull(points).vertices]
        except (QhullError, ValueError):
            candidates = np.array([points.min(axis=0), points.max(axis=0)])
    best = 0.0
    for start in range(0, len(candidates), 512):
        stop = start + 512
        block = candidates[start:stop]
        gaps = np.linalg.norm(block[:, None, :] - candidates[None, :, :], axis=-1)
        best = max(best, float(gaps.max()))
    return best


class GraspTarget:
    """
    A triangle mesh prepared for grasp evaluation: ray-casting scene, normals, mass properties.

    Build it once per object and pass it to :func:`evaluate_grasps` or :func:`grasp_quality`
    (they also accept a plain mesh and build it themselves).

    :ivar vertices: (V, 3) vertices used by at least one triangle (float64, mesh units).
    :ivar triangles: (T, 3) indices into :attr:`vertices`.
    :ivar triangle_normals: (T, 3) unit triangle normals from the winding (zero if degenerate).
    :ivar center_of_mass: (3,) torque origin and the spherical grasps' aim (see the module
        docstring).
    :ivar com_method: ``'solid'`` or ``'surface'``, how :attr:`center_of_mass` was computed.
    :ivar radius: largest distance from the centre of mass to a vertex, the torque scale rho.
    :ivar diameter: largest distance between two vertices, the object's size.
    :ivar closed: whether the mesh is closed and consistently oriented.
    """

    def __init__(
        self,
        vertices: ArrayLike,
        triangles: ArrayLike,
        *,
        center_of_mass: ArrayLike | None = None,
    ) -> None:
        """
        Prepare a mesh given as arrays.

        :param vertices: (V, 3) vertex coordinates, finite.
        :param triangles: (T, 3) vertex indices, T >= 1.
        :param center_of_mass: override the computed centre of mass (3,), e.g. a measured one.
        :raises ValueError: for an empty or invalid mesh.
        """
        import open3d as o3d

        verts = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(tris) == 0 or len(verts) == 0:
            raise ValueError('a grasp target needs a mesh with triangles')
        if tris.min() < 0 or tris.max() >= len(verts):
            raise ValueError('triangle indices out of range')
        if not np.all(np.isfinite(verts)):
            raise ValueError('mesh vertices must be finite')
        used, remap = np.unique(tris, return_inverse=True)
        self.vertices: FloatArray = verts[used]
        self.triangles: NDArray[np.int64] = remap.reshape(-1, 3).astype(np.int64)
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        normals = np.cross(b - a, c - a)
        lengths = np.linalg.norm(normals, axis=1, keepdims=True)
        self.triangle_normals: FloatArray = np.divide(
            normals, lengths, out=np.zeros_like(normals), where=lengths > 0.0
        )
        self.closed = is_closed(self.triangles)
        if center_of_mass is None:
            self.center_of_mass, self.com_method = _center_of_mass(self.vertices, self.triangles)
        else:
            self.center_of_mass = np.asarray(center_of_mass, dtype=np.float64).reshape(3)
            self.com_method = 'given'
        self.radius = float(np.linalg.norm(self.vertices - self.center_of_mass, axis=1).max())
        self.diameter = _diameter(self.vertices)
        if not self.radius > 0.0:
            raise ValueError('the mesh has no extent')
        self.scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(self.vertices.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(self.triangles.astype(np.int32))
        self.scene.add_triangles(mesh)

    @classmethod
    def from_mesh(cls, mesh: Any, *, center_of_mass: ArrayLike | None = None) -> GraspTarget:
        """
        Prepare any supported mesh.

        Accepted: a :class:`GraspTarget` (returned as is), an Open3D legacy or tensor triangle
        mesh, a ``(vertices, triangles)`` pair, or a mesh file path.

        :param mesh: the mesh.
        :param center_of_mass: override the computed centre of mass.
        :return: the prepared target.
        :raises ValueError: for an empty mesh or an unreadable file.
        :raises TypeError: for an unsupported type.
        """
        if isinstance(mesh, GraspTarget):
            if center_of_mass is None:
                return mesh
            return cls(mesh.vertices, mesh.triangles, center_of_mass=center_of_mass)
        if isinstance(mesh, (str, os.PathLike)):
            mesh = load_mesh(mesh)
        if isinstance(mesh, tuple) and len(mesh) == 2:
            return cls(mesh[0], mesh[1], center_of_mass=center_of_mass)
        if hasattr(mesh, 'vertices') and hasattr(mesh, 'triangles'):  # open3d.geometry
            return cls(
                np.asarray(mesh.vertices),
                np.asarray(mesh.triangles),
                center_of_mass=center_of_mass,
            )
        if hasattr(mesh, 'vertex') and hasattr(mesh, 'triangle'):  # open3d.t.geometry
            return cls(
                mesh.vertex.positions.numpy(),
                mesh.triangle.indices.numpy(),
                center_of_mass=center_of_mass,
            )
        raise TypeError(f'unsupported mesh type {type(mesh).__name__}')

    def __repr__(self) -> str:
        return (
            f'GraspTarget({len(self.vertices)} vertices, {len(self.triangles)} triangles, '
            f'closed={self.closed}, com={self.com_method}, diameter={self.diameter:.4g})'
        )


def load_mesh(path: str | os.PathLike[str]) -> Any:
    """
    Read a triangle mesh file (PLY, OFF, OBJ, STL, ... anything Open3D reads).

    :param path: the file.
    :return: an :class:`open3d.geometry.TriangleMesh`.
    :raises FileNotFoundError: when the file does not exist.
    :raises ValueError: when it holds no triangles.
    """
    import open3d as o3d

    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f'no such mesh file: {file}')
    mesh = o3d.io.read_triangle_mesh(str(file))
    if len(mesh.triangles) == 0:
        raise ValueError(f'{file} holds no triangles (is it a point cloud?)')
    return mesh


# Gripper ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ParallelJawGripper:
    """
    A parallel-jaw gripper (see the module docstring for the model). Lengths in mesh units.

    :ivar max_width: opening between the finger pads when open (> 0).
    :ivar finger_depth: finger length from the palm to the tips, along the approach (> 0).
    :ivar finger_width: finger (and palm) width across the closing direction (>= 0).
    :ivar retreat: how far the hand backs off after the palm touches (>= 0).
    :ivar palm_rays: rays across the opening on the palm (>= 2).
    :ivar width_rays: rays across the finger width, on the palm and on each fingertip (>= 1).
    """

    max_width: float
    finger_depth: float
    finger_width: float = 0.0
    retreat: float = 0.0
    palm_rays: int = 25
    width_rays: int = 3

    def __post_init__(self) -> None:
        if not self.max_width > 0.0:
            raise ValueError(f'max_width must be > 0, got {self.max_width}')
        if not self.finger_depth > 0.0:
            raise ValueError(f'finger_depth must be > 0, got {self.finger_depth}')
        if not self.finger_width >= 0.0:
            raise ValueError(f'finger_width must be >= 0, got {self.finger_width}')
        if not self.retreat >= 0.0:
            raise ValueError(f'retreat must be >= 0, got {self.retreat}')
        if self.palm_rays < 2 or self.width_rays < 1:
            raise ValueError('palm_rays must be >= 2 and width_rays >= 1')

    @classmethod
    def for_object(
        cls,
        size: float,
        *,
        width_factor: float = DEFAULT_WIDTH_FACTOR,
        depth_factor: float = DEFAULT_DEPTH_FACTOR,
        finger_width_factor: float = 0.1,
        retreat_factor: float = 0.01,
    ) -> ParallelJawGripper:
        """
        Return a gripper scaled to an object of the given size (its diameter), in its units.

        The defaults mirror the paper's large-opening five-finger hand with a parallel gripper
        that can span the whole object: opening 1.2 x the object's diameter, fingers half the
        diameter deep and a tenth of it wide, retreat 1 % of it.

        :param size: the object's size (e.g. :attr:`GraspTarget.diameter`), > 0.
        :param width_factor: ``max_width / size``.
        :param depth_factor: ``finger_depth / size``.
        :param finger_width_factor: ``finger_width / size``.
        :param retreat_factor: ``retreat / size``.
        :return: the gripper.
        """
        if not size > 0.0:
            raise ValueError(f'size must be > 0, got {size}')
        return cls(
            max_width=width_factor * size,
            finger_depth=depth_factor * size,
            finger_width=finger_width_factor * size,
            retreat=retreat_factor * size,
        )

    def default_contact_radius(self) -> float:
        """Return the soft-contact radius used when none is given: a quarter finger width."""
        return self.finger_width / 4.0


# Wrench space ----------------------------------------------------------------------------------


def _unit_rows(vectors: FloatArray) -> FloatArray:
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 0.0)


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
    t1 = _unit_rows(t1)
    return t1, np.cross(normals, t1)


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
    Return the primitive wrenches of contacts (see the module docstring), any leading shape.

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
    nrm = _unit_rows(np.asarray(normals, dtype=np.float64))
    centre = np.asarray(center, dtype=np.float64).reshape(3)
    refs = centre - pts if references is None else np.asarray(references, dtype=np.float64)
    refs = np.broadcast_to(refs, pts.shape).copy()
    t1, t2 = _tangents(nrm, refs)
    angles = 2.0 * np.pi * np.arange(cone_edges) / cone_edges
    forces = nrm[..., None, :] + friction * (
        np.cos(angles)[:, None] * t1[..., None, :] + np.sin(angles)[:, None] * t2[..., None, :]
    )  # (..., K, m, 3)
    arms = (pts - centre) / scale
    torques = np.cross(arms[..., None, :], forces)
    parts = [np.concatenate([forces, torques], axis=-1)]
    if torsion > 0.0:
        base = np.cross(arms, nrm)
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


# Grasp simulation ------------------------------------------------------------------------------


@dataclass(frozen=True)
class GraspQuality:
    """
    Quality of one simulated grasp.

    :ivar epsilon: Ferrari-Canny epsilon (0 when not force-closure).
    :ivar volume: volume V of the grasp wrench space hull.
    :ivar force_closure: ``epsilon > 0``.
    :ivar status: ``'grasped'``, ``'missed'``, ``'collision'`` or ``'no_contact'``.
    :ivar contacts: (2, 3) contact points (NaN when not grasped).
    :ivar normals: (2, 3) inward contact normals (NaN when not grasped).
    :ivar travel: how far the hand moved along the approach before closing (NaN if missed).
    """

    epsilon: float
    volume: float
    force_closure: bool
    status: str
    contacts: FloatArray
    normals: FloatArray
    travel: float


@dataclass
class GraspEvaluation:
    """
    Qualities of many grasps on one object, arrays in input order.

    :ivar epsilon: (G,) Ferrari-Canny epsilon.
    :ivar volume: (G,) wrench-space hull volume V (NaN when skipped by the closure
        prefilter of :func:`evaluate_grasps`).
    :ivar status: (G,) index into :data:`STATUS_NAMES`.
    :ivar contacts: (G, 2, 3) contact points (NaN when not grasped).
    :ivar normals: (G, 2, 3) inward normals (NaN when not grasped).
    :ivar travel: (G,) approach travel (NaN when missed).
    :ivar seconds: wall time of the evaluation.
    """

    epsilon: FloatArray
    volume: FloatArray
    status: NDArray[np.int8]
    contacts: FloatArray
    normals: FloatArray
    travel: FloatArray
    seconds: float = 0.0

    @property
    def force_closure(self) -> BoolArray:
        """(G,) whether each grasp is force-closure (epsilon > 0)."""
        return self.epsilon > 0.0

    def __len__(self) -> int:
        return len(self.epsilon)

    def status_counts(self) -> dict[str, int]:
        """Return how many grasps ended in each status."""
        counts = np.bincount(self.status, minlength=len(STATUS_NAMES))
        return {name: int(count) for name, count in zip(STATUS_NAMES, counts, strict=True)}

    def item(self, index: int) -> GraspQuality:
        """Return grasp `index` as a :class:`GraspQuality`."""
        return GraspQuality(
            epsilon=float(self.epsilon[index]),
            volume=float(self.volume[index]),
            force_closure=bool(self.epsilon[index] > 0.0),
            status=STATUS_NAMES[int(self.status[index])],
            contacts=self.contacts[index].copy(),
            normals=self.normals[index].copy(),
            travel=float(self.travel[index]),
        )


def _grasp_arrays(grasps: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return (positions, approaches, closings) of Grasp-like objects or an array triple."""
    if isinstance(grasps, tuple) and len(grasps) == 3 and not hasattr(grasps[0], 'position'):
        arrays = [np.asarray(part, dtype=np.float64).reshape(-1, 3) for part in grasps]
    else:
        items = list(grasps) if isinstance(grasps, Iterable) else [grasps]
        arrays = [
            np.array([np.asarray(getattr(g, name), dtype=np.float64) for g in items]).reshape(
                -1, 3
            )
            for name in ('position', 'approach', 'closing')
        ]
    if not len(arrays[0]) == len(arrays[1]) == len(arrays[2]):
        raise ValueError('positions, approaches and closings must have the same length')
    return arrays[0], arrays[1], arrays[2]


def _cast(scene: Any, origins: FloatArray, directions: FloatArray) -> dict[str, np.ndarray]:
    import open3d as o3d

    rays = np.concatenate([origins, directions], axis=-1).reshape(-1, 6).astype(np.float32)
    if len(rays) == 0:
        return {'t_hit': np.zeros(0), 'primitive_ids': np.zeros(0, dtype=np.int64)}
    hits = scene.cast_rays(o3d.core.Tensor(rays))
    shape = origins.shape[:-1]
    return {
        't_hit': hits['t_hit'].numpy().astype(np.float64).reshape(shape),
        'primitive_ids': hits['primitive_ids'].numpy().astype(np.int64).reshape(shape),
    }


def _may_be_force_closure(
    contacts: FloatArray, normals: FloatArray, friction: float, torsion: float
) -> BoolArray:
    """
    Return, per two-contact grasp, False when it is certainly not force-closure.

    Nguyen's test: two soft-finger contacts are force-closure only when the segment between
    them lies strictly inside both (circular) friction cones; the linearised wrench sets are
    inside the exact ones, so failing the test (or hard contacts, torsion 0) rules force
    closure out. Passing it does not prove force closure; the hull decides.
    """
    if torsion <= 0.0:
        return np.zeros(len(contacts), dtype=bool)
    line = contacts[:, 1] - contacts[:, 0]
    length = np.linalg.norm(line, axis=1)
    unit = np.divide(line, length[:, None], out=np.zeros_like(line), where=length[:, None] > 0)
    limit = np.cos(np.arctan(friction)) - 1e-9
    first = np.einsum('ij,ij->i', normals[:, 0], unit)
    second = -np.einsum('ij,ij->i', normals[:, 1], unit)
    return (length > 0.0) & (first > limit) & (second > limit)


def evaluate_grasps(
    mesh: Any,
    grasps: Any,
    *,
    gripper: ParallelJawGripper | None = None,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
    closure_prefilter: bool = False,
) -> GraspEvaluation:
    """
    Simulate and score many grasps on one mesh (see the module docstring), vectorised.

    :param mesh: a :class:`GraspTarget` or anything :meth:`GraspTarget.from_mesh` accepts.
    :param grasps: a sequence of grasp-like objects (``.position``, ``.approach``,
        ``.closing``, e.g. :class:`mvbb_ros.geometry.grasps.Grasp`), or a ``(positions, approaches,
        closings)`` triple of (G, 3) arrays.
    :param gripper: the gripper; default :meth:`ParallelJawGripper.for_object` of the mesh's
        diameter.
    :param friction: Coulomb friction coefficient mu (default 0.5).
    :param cone_edges: friction cone edges (default 8).
    :param contact_radius: soft-contact radius r for torsional friction (mesh units); default a
        quarter of the finger width; 0 for hard point contacts.
    :param closure_prefilter: skip the hull of grasps that Nguyen's two-contact test proves
        not force-closure (the contact line outside a friction cone): their epsilon is 0 as
        always and their volume is NaN (not computed). Several times faster on large sets; the
        epsilons and the force-closure grasps' volumes are unchanged.
    :return: the qualities, in input order.
    """
    start = time.perf_counter()
    target = GraspTarget.from_mesh(mesh)
    hand = gripper or ParallelJawGripper.for_object(target.diameter)
    radius = hand.default_contact_radius() if contact_radius is None else float(contact_radius)
    if not radius >= 0.0:
        raise ValueError(f'contact_radius must be >= 0, got {contact_radius}')
    torsion = 2.0 / 3.0 * friction * radius
    positions, approaches, closings = _grasp_arrays(grasps)
    count = len(positions)
    approach = _unit_rows(approaches)
    closing = closings - np.einsum('ij,ij->i', closings, approach)[:, None] * approach
    closing = _unit_rows(closing)
    if count and (
        np.any(np.linalg.norm(approach, axis=1) == 0.0)
        or np.any(np.linalg.norm(closing, axis=1) == 0.0)
    ):
        raise ValueError('every grasp needs an approach and a closing direction not along it')
    side = np.cross(approach, closing)
    half = hand.max_width / 2.0

    # 1-2. Approach: palm grid and fingertips, all along the approach direction.
    across = np.linspace(-half, half, hand.palm_rays)
    if hand.width_rays == 1:
        sideways = np.zeros(1)
    else:
        sideways = np.linspace(-hand.finger_width / 2, hand.finger_width / 2, hand.width_rays)
    palm_origins = (
        (positions - hand.finger_depth * approach)[:, None, None, :]
        + across[None, :, None, None] * closing[:, None, None, :]
        + sideways[None, None, :, None] * side[:, None, None, :]
    )
    palm_origins = palm_origins.reshape(count, -1, 3)
    finger_sign = np.array([1.0, -1.0])
    tip_origins = (
        positions[:, None, None, :]
        + finger_sign[None, :, None, None] * half * closing[:, None, None, :]
        + sideways[None, None, :, None] * side[:, None, None, :]
    ).reshape(count, -1, 3)
    origins = np.concatenate([palm_origins, tip_origins], axis=1)
    directions = np.broadcast_to(approach[:, None, :], origins.shape)
    t_hit = _cast(target.scene, origins, directions)['t_hit']
    n_palm = palm_origins.shape[1]
    palm_hit = t_hit[:, :n_palm].min(axis=1) if count else np.zeros(0)
    tip_hit = t_hit[:, n_palm:].min(axis=1) if count else np.zeros(0)
    missed = ~np.isfinite(palm_hit)
    travel = np.where(missed, np.nan, palm_hit - hand.retreat)
    collision = ~missed & (tip_hit < travel)

    status = np.full(count, GRASPED, dtype=np.int8)
    status[missed] = MISSED
    status[collision] = COLLISION
    contacts = np.full((count, 2, 3), np.nan)
    normals = np.full((count, 2, 3), np.nan)

    # 3. Close: one ray per finger from its open position at the pad centres' depth.
    live = np.flatnonzero(status == GRASPED)
    if len(live):
        pads = positions[live] + (travel[live] - hand.finger_depth / 2.0)[:, None] * approach[live]
        close_dirs = -finger_sign[None, :, None] * closing[live][:, None, :]  # (L, 2, 3)
        close_origins = pads[:, None, :] - half * close_dirs
        hits = _cast(target.scene, close_origins, close_dirs)
        distance = hits['t_hit']
        touched = np.all(np.isfinite(distance) & (distance <= hand.max_width), axis=1)
        status[live[~touched]] = NO_CONTACT
        good = live[touched]
        ids = hits['primitive_ids'][touched]
        points = close_origins[touched] + distance[touched][..., None] * close_dirs[touched]
        tri_normals = target.triangle_normals[ids]  # (L, 2, 3)
        along = np.einsum('lki,lki->lk', tri_normals, close_dirs[touched])
        inward = np.where((along >= 0.0)[..., None], tri_normals, -tri_normals)
        contacts[good] = points
        normals[good] = inward

    # Quality.
    epsilon = np.zeros(count)
    volume = np.zeros(count)
    good = np.flatnonzero(status == GRASPED)
    if closure_prefilter and len(good):
        hopeful = _may_be_force_closure(contacts[good], normals[good], friction, torsion)
        volume[good[~hopeful]] = np.nan
        good = good[hopeful]
    if len(good):
        wrenches = contact_wrenches(
            contacts[good],
            normals[good],
            center=target.center_of_mass,
            scale=target.radius,
            friction=friction,
            cone_edges=cone_edges,
            torsion=torsion,
            references=np.broadcast_to(approach[good][:, None, :], contacts[good].shape),
        )
        for row, index in enumerate(good):
            epsilon[index], volume[index] = wrench_space_quality(wrenches[row])
    return GraspEvaluation(
        epsilon=epsilon,
        volume=volume,
        status=status,
        contacts=contacts,
        normals=normals,
        travel=travel,
        seconds=time.perf_counter() - start,
    )


def grasp_quality(
    mesh: Any,
    grasp: Any,
    *,
    gripper: ParallelJawGripper | None = None,
    max_width: float | None = None,
    finger_depth: float | None = None,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
) -> GraspQuality:
    """
    Simulate one parallel-jaw grasp on a mesh and return its wrench-space quality.

    The gripper, placed at the grasp's pre-grasp pose, approaches until its palm touches,
    retreats, and closes; the two contacts with soft-finger friction give the grasp wrench
    space, scored by the Ferrari-Canny epsilon and the hull volume V (module docstring).

    :param mesh: a :class:`GraspTarget`, an Open3D triangle mesh, ``(vertices, triangles)``, or
        a mesh file path. Prepare a :class:`GraspTarget` once when scoring many grasps.
    :param grasp: an object with ``.position``, ``.approach`` and ``.closing`` (for example a
        :class:`mvbb_ros.geometry.grasps.Grasp`), all in the mesh's frame and units.
    :param gripper: the gripper; default :meth:`ParallelJawGripper.for_object` of the mesh's
        diameter, with `max_width` and `finger_depth` replacing its values when given.
    :param max_width: maximum opening (mesh units), when `gripper` is not given.
    :param finger_depth: finger length (mesh units), when `gripper` is not given.
    :param friction: Coulomb friction coefficient (default 0.5).
    :param cone_edges: friction cone edges (default 8).
    :param contact_radius: soft-contact radius (default a quarter finger width; 0 = hard).
    :return: epsilon, volume, force_closure, status, contacts and normals.
    """
    target = GraspTarget.from_mesh(mesh)
    if gripper is None:
        gripper = ParallelJawGripper.for_object(target.diameter)
        if max_width is not None or finger_depth is not None:
            gripper = ParallelJawGripper(
                max_width=gripper.max_width if max_width is None else max_width,
                finger_depth=gripper.finger_depth if finger_depth is None else finger_depth,
                finger_width=gripper.finger_width,
                retreat=gripper.retreat,
                palm_rays=gripper.palm_rays,
                width_rays=gripper.width_rays,
            )
    elif max_width is not None or finger_depth is not None:
        raise ValueError('give either gripper or max_width/finger_depth, not both')
    result = evaluate_grasps(
        target,
        [grasp],
        gripper=gripper,
        friction=friction,
        cone_edges=cone_edges,
        contact_radius=contact_radius,
    )
    return result.item(0)


# Spherical baseline ----------------------------------------------------------------------------


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
        """Return ``(positions, approaches, closings)`` for :func:`evaluate_grasps`."""
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
    turned = np.cross(approach, e_theta)
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
    from scipy.special import gammaln

    n = np.asarray(n, dtype=np.float64)
    return gammaln(n + 1) - gammaln(k + 1) - gammaln(n - k + 1)


# Comparison (Figure 6) -------------------------------------------------------------------------


@dataclass
class GraspSetResult:
    """
    One family of candidates on one object and their qualities.

    :ivar name: ``'spherical'``, ``'root box'`` or ``'t=0.94'`` style.
    :ivar evaluation: the qualities, in the candidates' order (box grasps: ranked best first).
    :ivar boxes: number of boxes the candidates came from (None for spherical).
    :ivar generate_seconds: time to make the candidates (box fit, decomposition, hypotheses).
    :ivar gain_threshold: the decomposition's t (None otherwise).
    """

    name: str
    evaluation: GraspEvaluation
    boxes: int | None = None
    generate_seconds: float = 0.0
    gain_threshold: float | None = None

    @property
    def candidates(self) -> int:
        """Return the number of grasps evaluated."""
        return len(self.evaluation)

    @property
    def seconds(self) -> float:
        """Return the generation plus evaluation time, seconds."""
        return self.generate_seconds + self.evaluation.seconds

    @property
    def best_index(self) -> int | None:
        """Index of the first grasp with the largest epsilon (None when none is FC)."""
        eps = self.evaluation.epsilon
        if not len(eps) or not eps.max() > 0.0:
            return None
        return int(np.argmax(eps))

    def best_epsilon(self) -> float:
        """Largest epsilon (0 without force-closure grasps)."""
        return float(self.evaluation.epsilon.max()) if self.candidates else 0.0

    def median_epsilon(self, *, force_closure_only: bool = False) -> float:
        """Median epsilon over all candidates (failures count 0), or over the FC ones only."""
        eps = self.evaluation.epsilon
        if force_closure_only:
            eps = eps[eps > 0.0]
        return float(np.median(eps)) if len(eps) else 0.0

    def force_closure_rate(self) -> float:
        """Fraction of candidates that are force-closure."""
        return float(self.evaluation.force_closure.mean()) if self.candidates else 0.0

    def first_reaching(self, epsilon: float) -> int | None:
        """1-based rank of the first candidate (in order) with epsilon >= `epsilon`, or None."""
        hits = np.flatnonzero(self.evaluation.epsilon >= epsilon)
        return int(hits[0]) + 1 if len(hits) else None


@dataclass
class QualityComparison:
    """
    The Figure 6 experiment on one object: spherical grasps against box grasps.

    :ivar name: the object's name.
    :ivar target: the prepared mesh.
    :ivar gripper: the gripper used for every set.
    :ivar sets: spherical first (when run), then the root box, then each threshold.
    :ivar settings: friction, cone edges, contact radius, spherical step, standoff.
    """

    name: str
    target: GraspTarget
    gripper: ParallelJawGripper
    sets: list[GraspSetResult] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def spherical(self) -> GraspSetResult | None:
        """Return the spherical baseline (None when it was not run)."""
        return next((s for s in self.sets if s.name == 'spherical'), None)

    @property
    def box_sets(self) -> list[GraspSetResult]:
        """Return the root box and decomposition sets."""
        return [s for s in self.sets if s.name != 'spherical']

    def claim(self, result: GraspSetResult) -> dict[str, Any]:
        """
        Test the claim on one box set.

        The claim: its best epsilon reaches 90 % of the best spherical epsilon with at most 1 %
        of the spherical candidates.

        :param result: a box set of this comparison.
        :return: ``quality_ratio``, ``candidate_ratio``, ``holds`` (None without a spherical
            baseline or when no spherical grasp is force-closure).
        """
        spherical = self.spherical
        if spherical is None or not spherical.best_epsilon() > 0.0:
            return {'quality_ratio': None, 'candidate_ratio': None, 'holds': None}
        ratio = result.best_epsilon() / spherical.best_epsilon()
        candidates = result.candidates / spherical.candidates
        return {
            'quality_ratio': ratio,
            'candidate_ratio': candidates,
            'holds': bool(
                ratio >= CLAIM_QUALITY_FRACTION - 1e-12
                and candidates <= CLAIM_CANDIDATE_FRACTION + 1e-12
            ),
        }

    def describe(self) -> str:
        """Return a few lines on the object, the gripper and the contact model."""
        target, hand, settings = self.target, self.gripper, self.settings
        size = target.diameter
        com = ', '.join(f'{v:.4g}' for v in target.center_of_mass)
        return '\n'.join(
            [
                f'{self.name}: {len(target.vertices)} vertices, {len(target.triangles)} '
                f'triangles, diameter D = {size:.4g} (mesh units), '
                f'{"closed" if target.closed else "open"} mesh',
                f'centre of mass ({target.com_method}) = ({com}); torque scale rho = '
                f'{target.radius:.4g}',
                f'gripper: opening {hand.max_width:.4g} ({hand.max_width / size:.2f} D), '
                f'finger depth {hand.finger_depth:.4g} ({hand.finger_depth / size:.2f} D), '
                f'finger width {hand.finger_width:.4g}, retreat {hand.retreat:.4g}',
                f'contacts: {"soft fingers" if settings.get("contact_radius") else "hard"}, '
                f'mu = {settings.get("friction")}, '
                f'{settings.get("cone_edges")} cone edges, contact radius '
                f'{settings.get("contact_radius"):.4g}; standoff {settings.get("standoff"):.4g}; '
                f'{settings.get("points")} points for the boxes',
            ]
        )

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready record: object, gripper, settings and the summary rows."""
        target = self.target
        return {
            'name': self.name,
            'object': {
                'vertices': len(target.vertices),
                'triangles': len(target.triangles),
                'closed': target.closed,
                'center_of_mass': [float(v) for v in target.center_of_mass],
                'center_of_mass_method': target.com_method,
                'radius': target.radius,
                'diameter': target.diameter,
            },
            'gripper': asdict(self.gripper),
            'settings': dict(self.settings),
            'sets': self.summary(),
        }

    def grasp_geometry(self, result: GraspSetResult, index: int) -> dict[str, float]:
        """
        Describe a grasped candidate's contacts, relative to the object's radius rho.

        :param result: one of this comparison's sets.
        :param index: a candidate of that set with two contacts.
        :return: ``separation`` (contact distance / rho), ``offset`` (distance from the centre
            of mass to the contact line / rho) and ``angle_deg`` (the larger angle between a
            contact normal and the contact line: 0 is perfectly antipodal).
        """
        contacts = result.evaluation.contacts[index]
        normals = result.evaluation.normals[index]
        line = contacts[1] - contacts[0]
        length = float(np.linalg.norm(line))
        unit = line / length if length > 0.0 else line
        arm = self.target.center_of_mass - contacts[0]
        offset = float(np.linalg.norm(arm - (arm @ unit) * unit))
        cosines = np.clip([normals[0] @ unit, -(normals[1] @ unit)], -1.0, 1.0)
        return {
            'separation': length / self.target.radius,
            'offset': offset / self.target.radius,
            'angle_deg': float(np.degrees(np.arccos(cosines.min()))),
        }

    def summary(self) -> list[dict[str, Any]]:
        """Return one JSON-ready row per set (what the table shows, and more)."""
        spherical = self.spherical
        target_eps = (
            CLAIM_QUALITY_FRACTION * spherical.best_epsilon()
            if spherical is not None and spherical.best_epsilon() > 0.0
            else None
        )
        rows = []
        for result in self.sets:
            best = result.best_index
            row: dict[str, Any] = {
                'set': result.name,
                'boxes': result.boxes,
                'candidates': result.candidates,
                'force_closure': int(result.evaluation.force_closure.sum()),
                'force_closure_rate': result.force_closure_rate(),
                'best_epsilon': result.best_epsilon(),
                'best_volume': None if best is None else float(result.evaluation.volume[best]),
                'median_epsilon': result.median_epsilon(),
                'median_epsilon_fc': result.median_epsilon(force_closure_only=True),
                'generate_seconds': result.generate_seconds,
                'evaluate_seconds': result.evaluation.seconds,
                'status': result.evaluation.status_counts(),
                'best_grasp': None if best is None else self.grasp_geometry(result, best),
            }
            if target_eps is not None:
                if result.name == 'spherical':
                    # Expected draws, in random order without replacement, to the first success.
                    hits = int(np.count_nonzero(result.evaluation.epsilon >= target_eps))
                    row['to_90'] = (result.candidates + 1) / (hits + 1)
                else:
                    row['to_90'] = result.first_reaching(target_eps)
                    row.update(self.claim(result))
            if spherical is not None and result is not spherical:
                row['spherical_same_budget'] = expected_best_of(
                    spherical.evaluation.epsilon, result.candidates
                )
            rows.append(row)
        return rows


def compare_grasp_sets(
    mesh: Any,
    points: ArrayLike | None = None,
    *,
    name: str = 'object',
    gripper: ParallelJawGripper | None = None,
    thresholds: Sequence[float] = PAPER_THRESHOLDS,
    spherical_step: float | None = DEFAULT_SPHERICAL_STEP_DEG,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
    standoff: float | None = None,
    min_points: int | None = None,
    seed: int = 0,
    closure_prefilter: bool = True,
    progress: Any = None,
) -> QualityComparison:
    """
    Run the Figure 6 experiment on one object.

    Candidates: the spherical grasps (sphere radius = the object's radius plus `standoff`), the
    24 face grasps of the root box of `points`, and the face grasps of the decomposition of
    `points` at each threshold (occluded faces removed; no width filter bites, the gripper
    spans the object). Every set is scored with the same gripper and contact model.

    :param mesh: the object's mesh (anything :meth:`GraspTarget.from_mesh` accepts).
    :param points: (N, 3) points to fit boxes to (default the mesh's vertices; the paper used
        the model vertices).
    :param name: the object's name for reports.
    :param gripper: default :meth:`ParallelJawGripper.for_object` of the mesh's diameter.
    :param thresholds: gain thresholds t of the decompositions.
    :param spherical_step: spherical grid step in degrees; None skips the baseline.
    :param friction: Coulomb friction coefficient.
    :param cone_edges: friction cone edges.
    :param contact_radius: soft-contact radius (default a quarter finger width).
    :param standoff: pre-grasp distance off the faces and the sphere (default 5 % of the
        object's diameter).
    :param min_points: the decomposition's ``min_points`` (default its own default).
    :param seed: the box fit's random seed.
    :param closure_prefilter: skip the hulls of grasps proven not force-closure (their V is
        NaN; see :func:`evaluate_grasps`), default True.
    :param progress: optional callable taking a message string.
    :return: the comparison.
    """
    from mvbb_ros.geometry.decomposition import decompose
    from mvbb_ros.geometry.fit import minimum_bounding_box
    from mvbb_ros.geometry.grasps import grasp_hypotheses

    def say(message: str) -> None:
        if progress is not None:
            progress(message)

    target = GraspTarget.from_mesh(mesh)
    hand = gripper or ParallelJawGripper.for_object(target.diameter)
    cloud = target.vertices if points is None else np.asarray(points, dtype=np.float64)
    off = 0.05 * target.diameter if standoff is None else float(standoff)
    quality = {
        'friction': friction,
        'cone_edges': cone_edges,
        'contact_radius': contact_radius,
        'closure_prefilter': closure_prefilter,
    }
    comparison = QualityComparison(
        name=name,
        target=target,
        gripper=hand,
        settings={
            **quality,
            'contact_radius': (
                hand.default_contact_radius() if contact_radius is None else contact_radius
            ),
            'spherical_step': spherical_step,
            'standoff': off,
            'points': len(cloud),
        },
    )
    hypothesis_options = {'gripper_max_width': hand.max_width, 'standoff': off}

    if spherical_step is not None:
        started = time.perf_counter()
        sphere = spherical_grasps(target.center_of_mass, target.radius + off, spherical_step)
        generated = time.perf_counter() - started
        say(f'{name}: {len(sphere)} spherical grasps ...')
        evaluation = evaluate_grasps(target, sphere.arrays(), gripper=hand, **quality)
        comparison.sets.append(GraspSetResult('spherical', evaluation, None, generated))

    started = time.perf_counter()
    root = minimum_bounding_box(cloud, seed=seed)
    grasps = grasp_hypotheses([root], **hypothesis_options)
    generated = time.perf_counter() - started
    say(f'{name}: root box, {len(grasps)} grasps ...')
    evaluation = evaluate_grasps(target, grasps, gripper=hand, **quality)
    comparison.sets.append(GraspSetResult('root box', evaluation, 1, generated))

    for threshold in thresholds:
        started = time.perf_counter()
        options: dict[str, Any] = {'gain_threshold': float(threshold), 'seed': seed}
        if min_points is not None:
            options['min_points'] = min_points
        decomposition = decompose(cloud, **options)
        grasps = grasp_hypotheses(decomposition, **hypothesis_options)
        generated = time.perf_counter() - started
        say(f'{name}: t = {threshold:g}, {len(decomposition.leaves)} boxes, {len(grasps)} grasps')
        evaluation = evaluate_grasps(target, grasps, gripper=hand, **quality)
        comparison.sets.append(
            GraspSetResult(
                f't={threshold:.2f}',
                evaluation,
                len(decomposition.leaves),
                generated,
                gain_threshold=float(threshold),
            )
        )
    return comparison


# Reports ---------------------------------------------------------------------------------------


def _number(value: float | None, digits: int = 4) -> str:
    if value is None:
        return '-'
    return f'{value:.{digits}f}'


def _geometry_text(geometry: dict[str, float] | None) -> str:
    if geometry is None:
        return '-'
    return (
        f'{geometry["separation"]:.2f} / {geometry["offset"]:.2f} / '
        f'{geometry["angle_deg"]:.0f} deg'
    )


def format_comparison(comparison: QualityComparison, *, markdown: bool = True) -> str:
    """
    Return the comparison as a table, one row per candidate set.

    Columns: set, boxes, candidates, force-closure rate, best epsilon (and its V), median
    epsilon over all candidates and over the force-closure ones, rank of the first candidate
    reaching 90 % of the best spherical epsilon (spherical: expected random draws), best epsilon
    as a fraction of the best spherical one, candidates as a fraction of the spherical count,
    whether the claim holds, the expected best epsilon of as many random spherical grasps
    (:func:`expected_best_of`), the best grasp's geometry
    (:meth:`QualityComparison.grasp_geometry`: contact separation and contact line offset from
    the centre of mass, both / rho, and the larger normal-to-line angle), the failures (finger
    collisions / no contact / missed) and time (generation + evaluation).

    :param comparison: the experiment's result.
    :param markdown: a Markdown table (default) or aligned plain text.
    :return: the table.
    """
    header = [
        'set',
        'boxes',
        'cand.',
        'FC rate',
        'best eps',
        'V (best)',
        'median eps',
        'median eps (FC)',
        'to 90 %',
        'eps / sph.',
        'cand. / sph.',
        'claim',
        'sph. same budget',
        'best: sep / off / angle',
        'failures c / n / m',
        'time s',
    ]
    table = []
    for row in comparison.summary():
        to_90 = row.get('to_90')
        if isinstance(to_90, float):
            to_90_text = f'~{to_90:.0f}'
        else:
            to_90_text = '-' if to_90 is None else str(to_90)
        holds = row.get('holds')
        table.append(
            [
                row['set'],
                '-' if row['boxes'] is None else str(row['boxes']),
                str(row['candidates']),
                f'{100 * row["force_closure_rate"]:.1f} %',
                _number(row['best_epsilon']),
                _number(row['best_volume'], 5),
                _number(row['median_epsilon']),
                _number(row['median_epsilon_fc']),
                to_90_text,
                (
                    '-'
                    if row.get('quality_ratio') is None
                    else f'{100 * row["quality_ratio"]:.1f} %'
                ),
                (
                    '-'
                    if row.get('candidate_ratio') is None
                    else f'{100 * row["candidate_ratio"]:.2f} %'
                ),
                '-' if holds is None else ('yes' if holds else 'no'),
                _number(row.get('spherical_same_budget')),
                _geometry_text(row['best_grasp']),
                '{collision} / {no_contact} / {missed}'.format(**row['status']),
                f'{row["generate_seconds"] + row["evaluate_seconds"]:.1f}',
            ]
        )
    if markdown:
        lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
        lines += ['| ' + ' | '.join(cells) + ' |' for cells in table]
        return '\n'.join(lines)
    widths = [max(len(header[i]), *(len(r[i]) for r in table)) for i in range(len(header))]
    lines = ['  '.join(h.rjust(w) for h, w in zip(header, widths, strict=True))]
    lines += ['  '.join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in table]
    return '\n'.join(lines)


#: Marker colours of the box sets in :func:`plot_quality_space`.
_SET_COLOURS = ('tab:red', 'tab:orange', 'tab:green', 'tab:blue', 'tab:purple', 'tab:brown')


def plot_quality_space(
    comparison: QualityComparison, path: str | os.PathLike[str], *, title: str | None = None
) -> Path:
    """
    Write the paper's Figure 6 for one object: the (epsilon, V) quality space.

    Like the paper, only force-closure grasps are drawn: every spherical grasp as a grey cross,
    the best-epsilon spherical grasp as a black square, and for each box set its grasps as small
    dots and its best-epsilon grasp as a large diamond labelled (candidates, set). Written
    atomically with matplotlib's Agg canvas.

    :param comparison: the experiment's result.
    :param path: the PNG file to write.
    :param title: the figure title (default the object's name and the gripper).
    :return: the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mvbb_ros.cli.atomic import atomic_path

    figure = Figure(figsize=(7.5, 5.5), dpi=120)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(1, 1, 1)
    spherical = comparison.spherical
    if spherical is not None:
        fc = spherical.evaluation.force_closure
        axes.scatter(
            spherical.evaluation.epsilon[fc],
            spherical.evaluation.volume[fc],
            marker='x',
            s=9,
            linewidths=0.5,
            color='0.65',
            label=f'spherical ({int(fc.sum())} FC of {spherical.candidates})',
            zorder=1,
        )
        best = spherical.best_index
        if best is not None:
            axes.scatter(
                [spherical.evaluation.epsilon[best]],
                [spherical.evaluation.volume[best]],
                marker='s',
                s=70,
                color='black',
                label=f'best spherical (eps {spherical.best_epsilon():.4f})',
                zorder=4,
            )
    offsets = ((8, 8), (8, -14), (8, 20), (8, -26), (8, 32), (8, -38))
    for colour, offset, result in zip(_SET_COLOURS, offsets, comparison.box_sets, strict=False):
        fc = result.evaluation.force_closure
        axes.scatter(
            result.evaluation.epsilon[fc],
            result.evaluation.volume[fc],
            marker='.',
            s=22,
            color=colour,
            alpha=0.6,
            zorder=2,
        )
        best = result.best_index
        label = f'{result.name}: {int(fc.sum())} FC of {result.candidates}'
        if best is None:
            axes.scatter([], [], marker='D', color=colour, label=label + ' (none FC)')
            continue
        eps, vol = result.evaluation.epsilon[best], result.evaluation.volume[best]
        axes.scatter(
            [eps],
            [vol],
            marker='D',
            s=70,
            color=colour,
            edgecolors='black',
            label=f'{label}, best eps {eps:.4f}',
            zorder=5,
        )
        axes.annotate(
            f'({result.candidates}, {result.name})',
            (eps, vol),
            textcoords='offset points',
            xytext=offset,
            fontsize=7,
            color=colour,
        )
    hand = comparison.gripper
    axes.set_xlabel('epsilon (Ferrari-Canny, torques / object radius)')
    axes.set_ylabel('V (grasp wrench space volume)')
    axes.set_xlim(left=0.0)
    axes.set_ylim(bottom=0.0)
    axes.grid(True, linewidth=0.3)
    axes.legend(fontsize=7, loc='upper left')
    size = comparison.target.diameter
    axes.set_title(
        title
        or (
            f'{comparison.name}: grasp quality space (only force-closure grasps)\n'
            f'parallel jaw: opening {hand.max_width / size:.2f} D, '
            f'fingers {hand.finger_depth / size:.2f} D; mu = '
            f'{comparison.settings.get("friction", DEFAULT_FRICTION):g}'
        ),
        fontsize=9,
    )
    figure.tight_layout()
    target = Path(path)
    with atomic_path(target) as tmp:
        figure.savefig(tmp, format='png')
    return target
