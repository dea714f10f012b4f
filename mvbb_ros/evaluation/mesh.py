"""
The object of a grasp-quality experiment: a triangle mesh ready for ray casting.

:class:`GraspTarget` holds the mesh as an Open3D ray-casting scene with its triangle normals,
centre of mass (the solid's centroid for a closed mesh, the surface's otherwise), radius (the
torque scale) and diameter (the object's size, which scales the gripper). The evaluation
protocol is written out in ``docs/evaluation_protocol.md``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mvbb_ros.arrays import cross, FloatArray, IndexArray
import numpy as np
from numpy.typing import ArrayLike, NDArray
import open3d as o3d
from scipy.spatial import ConvexHull, QhullError


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
        six_volumes = np.einsum('ij,ij->i', a, cross(b, c))
        total = float(six_volumes.sum())
        scale = float(np.abs(six_volumes).sum())
        if scale > 0.0 and abs(total) > 1e-12 * scale:
            centre = (six_volumes[:, None] * (a + b + c)).sum(axis=0) / (4.0 * total)
            return origin + centre, 'solid'
    areas = np.linalg.norm(cross(b - a, c - a), axis=1)
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

    Build it once per object and pass it to the simulation (:mod:`mvbb_ros.evaluation.simulation`;
    it also accepts a plain mesh and builds the target itself).

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
        normals = cross(b - a, c - a)
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

    def cast(self, origins: ArrayLike, directions: ArrayLike) -> tuple[FloatArray, IndexArray]:
        """
        Cast rays at the mesh, any leading shape.

        :param origins: (..., 3) ray origins.
        :param directions: (..., 3) ray directions (broadcast against `origins`); the hit
            distance is in units of their length.
        :return: ``(t_hit, primitive_ids)`` of shape (...): the hit distance (inf for a miss)
            and the triangle hit (an invalid id for a miss).
        """
        start = np.asarray(origins, dtype=np.float64)
        direction = np.broadcast_to(np.asarray(directions, dtype=np.float64), start.shape)
        shape = start.shape[:-1]
        rays = np.concatenate([start, direction], axis=-1).reshape(-1, 6).astype(np.float32)
        if len(rays) == 0:
            return np.zeros(shape), np.zeros(shape, dtype=np.intp)
        hits = self.scene.cast_rays(o3d.core.Tensor(rays))
        return (
            hits['t_hit'].numpy().astype(np.float64).reshape(shape),
            hits['primitive_ids'].numpy().astype(np.intp).reshape(shape),
        )

    def inward_normals(self, primitive_ids: ArrayLike, directions: ArrayLike) -> FloatArray:
        """
        Return the normals of the triangles hit, turned along the rays that hit them (..., 3).

        A finger pushing along its ray pushes along this normal, into the object, whatever the
        triangle's winding.

        :param primitive_ids: (...) triangles hit (valid ids only).
        :param directions: (..., 3) the rays' directions.
        """
        normals = self.triangle_normals[np.asarray(primitive_ids, dtype=np.intp)]
        along = np.einsum('...i,...i->...', normals, np.asarray(directions, dtype=np.float64))
        return np.where((along >= 0.0)[..., None], normals, -normals)

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
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f'no such mesh file: {file}')
    mesh = o3d.io.read_triangle_mesh(str(file))
    if len(mesh.triangles) == 0:
        raise ValueError(f'{file} holds no triangles (is it a point cloud?)')
    return mesh
