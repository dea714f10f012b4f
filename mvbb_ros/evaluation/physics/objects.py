"""
The objects of the physics trial: a mesh, its convex pieces for collision, and a density.

Three sources, all in metres:

* :func:`random_object`: pybullet_data's 1,000 procedurally generated objects
  (``random_urdfs/NNN/NNN.obj``), each a union of convex pieces (the OBJ's ``o`` groups), given a
  seeded size so that the set spans household sizes (:func:`random_scale`) and split by name into a
  development set (000-499) and a validation set (500-999) that nothing is tuned on
  (:func:`random_object_split`).
* :func:`shared_mesh_objects`: the eleven shared meshes of the single-view benchmark, scaled and
  stood up as :mod:`mvbb_ros.evaluation.views` does (its ``TABLE_MODELS``).
* :func:`mesh_folder_objects`: every PLY/OBJ/STL of a folder, in the units given.

Concave meshes are cut into convex parts by CoACD (:func:`convex_parts`), cached on disk by a hash
of the mesh and the settings, since a decomposition costs seconds to minutes.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import hashlib
import os
from pathlib import Path
from typing import Literal

from mvbb_ros.arrays import FloatArray, IndexArray
from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.evaluation.mesh import load_mesh
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

#: Parts of an object: (vertices (V, 3), triangles (F, 3)) of each convex piece, object frame.
Parts = tuple[tuple[FloatArray, IndexArray], ...]

#: Stated density (kg/m^3) of every object: half that of water, between hollow household goods
#: (a boxed cereal packet, a plastic bottle: about 100-300) and solid wood or fruit (600-1000).
#: The meshes are solids; real objects of these sizes are mostly hollow or light.
DEFAULT_DENSITY = 500.0

#: Longest side of the random objects' axis-aligned box in their own frame: uniform in this
#: range (metres), seeded per object (:func:`random_scale`).
RANDOM_LENGTH_RANGE = (0.04, 0.16)
#: The random objects 000-499 are the development set, 500-999 the validation set.
RANDOM_COUNT = 1000
DEVELOPMENT_END = 500

#: CoACD's settings (its defaults: concavity threshold 0.05, seed 0), part of the cache key.
COACD_THRESHOLD = 0.05
COACD_SEED = 0

#: A mesh is convex when no vertex or triangle centre lies deeper inside its hull than this
#: share of its longest side.
CONVEX_TOLERANCE = 0.005

#: The extensions :func:`mesh_folder_objects` reads.
MESH_SUFFIXES = ('.ply', '.obj', '.stl')
_UNITS = {'m': 1.0, 'cm': 0.01, 'mm': 0.001}


@dataclass(frozen=True, eq=False)
class PhysicsObject:
    """
    A rigid object for the trial, in its own frame (metres).

    :ivar name: short name (``'random_042'``, ``'mug'``, the file's stem).
    :ivar vertices: (V, 3) the mesh's vertices.
    :ivar triangles: (F, 3) the mesh's triangles.
    :ivar parts: the convex pieces the engine collides with (each its own convex hull).
    :ivar density: kg/m^3; the mass is the density times :attr:`volume`.
    """

    name: str
    vertices: FloatArray
    triangles: IndexArray
    parts: Parts
    density: float = DEFAULT_DENSITY

    def __post_init__(self) -> None:
        if not self.parts:
            raise ValueError(f'{self.name}: an object needs at least one convex part')
        if not self.density > 0.0:
            raise ValueError(f'{self.name}: density must be > 0, got {self.density}')

    @functools.cached_property
    def volume(self) -> float:
        """Volume of the union of the convex parts (m^3): what the engine collides with."""
        return union_volume(self.parts)

    @property
    def mass(self) -> float:
        """Mass (kg): density times the parts' union volume."""
        return self.density * self.volume

    @property
    def extent(self) -> FloatArray:
        """Size (3,) of the mesh's axis-aligned box in the object frame (metres)."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


def hull_of(points: ArrayLike) -> tuple[FloatArray, IndexArray]:
    """
    Return the convex hull of `points` as (vertices, outward triangles).

    :raises ValueError: when the points span no volume.
    """
    points = np.asarray(points, dtype=np.float64)
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError) as error:
        raise ValueError(f'the points span no volume ({len(points)} points)') from error
    used = np.unique(hull.simplices)
    remap = np.full(len(points), -1, dtype=np.intp)
    remap[used] = np.arange(len(used))
    triangles = remap[hull.simplices]
    vertices = points[used]
    # Orient every triangle outwards, by the facet's plane normal.
    normals = np.cross(
        vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
        vertices[triangles[:, 2]] - vertices[triangles[:, 0]],
    )
    flip = np.einsum('ij,ij->i', normals, hull.equations[:, :3]) < 0.0
    triangles[flip] = triangles[flip][:, ::-1]
    return vertices, triangles.astype(np.intp)


def _hull_volume(vertices: FloatArray) -> float:
    try:
        return float(ConvexHull(vertices).volume)
    except (QhullError, ValueError):
        return 0.0


def mesh_volume(vertices: ArrayLike, triangles: ArrayLike) -> float:
    """Signed volume of a closed, outward-oriented triangle mesh (m^3), by tetrahedra."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.intp)
    return float(np.einsum('ij,ij->i', v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)


def union_volume(parts: Parts, points: int = 100_000) -> float:
    """
    Volume of the union of convex parts (m^3), counted on a grid.

    The parts' box is cut into about `points` cubes; a cube counts when its centre is inside any
    part. Deterministic; the error is of the order of the cubes on the surface (a few per cent at
    the default).
    """
    low = np.min([vertices.min(axis=0) for vertices, _ in parts], axis=0)
    high = np.max([vertices.max(axis=0) for vertices, _ in parts], axis=0)
    size = np.maximum(high - low, 1e-9)
    step = float(np.prod(size) / points) ** (1.0 / 3.0)
    axes = [
        low[i] + step * (np.arange(max(1, int(np.ceil(size[i] / step)))) + 0.5) for i in range(3)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    inside = np.zeros(len(grid), dtype=bool)
    total = 0.0  # the sum of the parts' volumes bounds their union from above
    for vertices, _ in parts:
        try:
            hull = ConvexHull(vertices)
        except (QhullError, ValueError):
            continue
        equations, total = hull.equations, total + float(hull.volume)
        near = np.all((grid >= vertices.min(axis=0)) & (grid <= vertices.max(axis=0)), axis=1)
        candidates = np.flatnonzero(near & ~inside)
        for chunk in np.array_split(candidates, max(1, len(candidates) // 20_000)):
            offsets = grid[chunk] @ equations[:, :3].T + equations[:, 3]
            inside[chunk[np.all(offsets <= 0.0, axis=1)]] = True
    return min(float(inside.sum()) * step**3, total)


def default_cache_dir() -> Path:
    """Return where :func:`convex_parts` keeps parts: in ``$MVBB_CACHE_DIR`` or ``~/.cache``."""
    base = os.environ.get('MVBB_CACHE_DIR') or Path.home() / '.cache' / 'mvbb_ros'
    return Path(base) / 'convex_parts'


def _edge_manifold(triangles: IndexArray) -> bool:
    """Tell whether every edge of the mesh is in at most two triangles (holes allowed)."""
    edges = np.sort(
        np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1
    )
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(counts.max() <= 2)


def _preprocess_mode(triangles: IndexArray) -> str:
    """
    Return CoACD's preprocessing for the mesh: 'off' for an edge-manifold mesh, else 'auto'.

    CoACD's 'auto' remeshes every mesh that is not watertight on a voxel grid first, which made
    its search many times slower on the open but edge-manifold shared meshes (a can) for parts
    of the same volume; meshes with edges in three or more triangles still need it.
    """
    return 'off' if _edge_manifold(triangles) else 'auto'


def _cache_key(vertices: FloatArray, triangles: IndexArray) -> str:
    import coacd  # noqa: PLC0415 (only needed for the version)

    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(vertices, dtype='<f8').tobytes())
    digest.update(np.ascontiguousarray(triangles, dtype='<i8').tobytes())
    version = getattr(coacd, '__version__', '1.0.14')
    mode = _preprocess_mode(triangles)
    digest.update(f'coacd {version} {COACD_THRESHOLD} {COACD_SEED} {mode}'.encode())
    return digest.hexdigest()


def _is_convex(vertices: FloatArray, triangles: IndexArray) -> bool:
    """
    Tell whether the mesh is its own hull: every vertex and triangle centre on the hull's surface.

    On the surface means within :data:`CONVEX_TOLERANCE` of the longest side; open meshes (a
    surface without a bottom) count too, their hull being the solid they bound.
    """
    try:
        hull = ConvexHull(vertices)
    except (QhullError, ValueError):
        return False
    tolerance = CONVEX_TOLERANCE * float(np.ptp(vertices, axis=0).max())
    centres = vertices[triangles].mean(axis=1)
    for points in (vertices, centres):
        for start in range(0, len(points), 4096):  # in blocks: big meshes' hulls have many facets
            stop = start + 4096
            block = points[start:stop]
            depth = -(block @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)
            if np.any(depth > tolerance):
                return False
    return True


def convex_parts(
    vertices: ArrayLike,
    triangles: ArrayLike,
    cache_dir: str | os.PathLike[str] | None = None,
) -> Parts:
    """
    Return convex pieces whose union is the mesh, for the engine's collisions.

    A convex mesh (every vertex on its hull) is its own hull; anything else is cut by CoACD
    (Wei et al. 2022; concavity threshold :data:`COACD_THRESHOLD`, seed :data:`COACD_SEED`, its
    remeshing only for meshes that are not edge-manifold: :func:`_preprocess_mode`). The
    result is kept in `cache_dir` (default :func:`default_cache_dir`) under the SHA-256 of the
    vertices, triangles and settings, written atomically, so the next call reads it back.

    :param vertices: (V, 3) metres.
    :param triangles: (F, 3) vertex indices.
    :param cache_dir: the cache folder.
    :return: the parts, each (hull vertices, outward triangles).
    """
    v = np.array(vertices, dtype=np.float64)
    t = np.array(triangles, dtype=np.intp)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or not len(t):
        raise ValueError(
            f'convex_parts needs (V, 3) vertices and (F, 3) triangles, got {v.shape}, {t.shape}'
        )
    if not np.all(np.isfinite(v)) or t.min() < 0 or t.max() >= len(v):
        raise ValueError('convex_parts: non-finite vertices or triangle indices out of range')
    if _is_convex(v, t):
        return (hull_of(v),)
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = folder / f'{_cache_key(v, t)}.npz'
    if path.is_file():
        with np.load(path) as stored:
            count = len(stored.files) // 2
            return tuple((stored[f'v{i}'], stored[f't{i}'].astype(np.intp)) for i in range(count))
    parts = _coacd(v, t)
    with atomic_path(path) as tmp, open(tmp, 'wb') as handle:
        arrays = {}
        for i, (part_vertices, part_triangles) in enumerate(parts):
            arrays[f'v{i}'] = part_vertices
            arrays[f't{i}'] = part_triangles.astype(np.int64)
        np.savez(handle, **arrays)  # type: ignore[arg-type]
    return parts


def _coacd(vertices: FloatArray, triangles: IndexArray) -> Parts:
    import coacd  # noqa: PLC0415 (a compiled library that only decomposition needs)

    coacd.set_log_level('error')
    pieces = coacd.run_coacd(
        coacd.Mesh(vertices, triangles),
        threshold=COACD_THRESHOLD,
        seed=COACD_SEED,
        preprocess_mode=_preprocess_mode(triangles),
    )
    parts = []
    for piece_vertices, _ in pieces:
        try:
            parts.append(hull_of(np.asarray(piece_vertices, dtype=np.float64)))
        except ValueError:
            continue  # a flat sliver: no volume to collide with
    if not parts:
        raise ValueError('CoACD returned no piece with a volume')
    return tuple(parts)


def random_urdfs_dir() -> Path:
    """Return the folder of pybullet_data's random objects (``random_urdfs``)."""
    import pybullet_data  # noqa: PLC0415 (pure data; only these objects need it)

    return Path(pybullet_data.getDataPath()) / 'random_urdfs'


def random_object_split(index: int) -> Literal['development', 'validation']:
    """Return the set of random object `index`: 'development' (0-499) or 'validation' (500-999)."""
    if not 0 <= index < RANDOM_COUNT:
        raise ValueError(f'random objects are numbered 0-{RANDOM_COUNT - 1}, got {index}')
    return 'development' if index < DEVELOPMENT_END else 'validation'


def random_scale(index: int, seed: int = 0) -> float:
    """
    Return the longest side (metres) random object `index` is given for `seed`.

    Uniform in :data:`RANDOM_LENGTH_RANGE`, drawn from ``numpy.random.default_rng([seed, index])``,
    so each object's size depends only on its number and the seed.
    """
    low, high = RANDOM_LENGTH_RANGE
    return float(np.random.default_rng([seed, index]).uniform(low, high))


def read_obj_groups(path: str | os.PathLike[str]) -> list[tuple[FloatArray, IndexArray]]:
    """
    Read an OBJ file's ``o``/``g`` groups, each as (vertices, triangles) with its own vertices.

    Polygons are fanned into triangles; texture and normal indices are ignored.
    """
    points: list[list[float]] = []
    groups: list[list[list[int]]] = [[]]
    for line in Path(path).read_text().splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == 'v':
            points.append([float(x) for x in fields[1:4]])
        elif fields[0] in ('o', 'g') and groups[-1]:
            groups.append([])
        elif fields[0] == 'f':
            corners = [int(field.split('/')[0]) for field in fields[1:]]
            corners = [c - 1 if c > 0 else len(points) + c for c in corners]
            groups[-1].extend(
                [corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)
            )
    all_points = np.asarray(points, dtype=np.float64)
    result = []
    for faces in groups:
        if not faces:
            continue
        face_array = np.asarray(faces, dtype=np.intp)
        used, inverse = np.unique(face_array, return_inverse=True)
        result.append((all_points[used], inverse.reshape(-1, 3).astype(np.intp)))
    return result


def random_object(index: int, seed: int = 0, density: float = DEFAULT_DENSITY) -> PhysicsObject:
    """
    Return pybullet_data's random object `index`, scaled by :func:`random_scale`.

    The object frame is the OBJ's axes with the origin at the centre of its box. The parts are the
    generator's own convex pieces (the OBJ's groups, each taken as its hull; no decomposition), the
    mesh is the pieces together (they overlap; their outer surface is the object).
    """
    random_object_split(index)
    name = f'{index:03d}'
    groups = read_obj_groups(random_urdfs_dir() / name / f'{name}.obj')
    everything = np.concatenate([vertices for vertices, _ in groups])
    low, high = everything.min(axis=0), everything.max(axis=0)
    scale = random_scale(index, seed) / float((high - low).max())
    centre = (low + high) / 2.0
    vertices, triangles, parts, offset = [], [], [], 0
    for group_vertices, group_triangles in groups:
        scaled = (group_vertices - centre) * scale
        vertices.append(scaled)
        triangles.append(group_triangles + offset)
        offset += len(scaled)
        try:
            parts.append(hull_of(scaled))
        except ValueError:
            continue
    return PhysicsObject(
        name=f'random_{name}',
        vertices=np.concatenate(vertices),
        triangles=np.concatenate(triangles),
        parts=tuple(parts),
        density=density,
    )


def _object_from_mesh(
    name: str,
    vertices: ArrayLike,
    triangles: ArrayLike,
    density: float,
    cache_dir: str | os.PathLike[str] | None,
) -> PhysicsObject:
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.intp)
    return PhysicsObject(name, v, t, convex_parts(v, t, cache_dir), density)


def _models_dir(data_dir: str | os.PathLike[str]) -> Path:
    folder = Path(data_dir)
    return folder / 'models' if (folder / 'models').is_dir() else folder


def shared_mesh_objects(
    data_dir: str | os.PathLike[str],
    cache_dir: str | os.PathLike[str] | None = None,
    density: float = DEFAULT_DENSITY,
) -> list[PhysicsObject]:
    """
    Return the shared meshes (:data:`~mvbb_ros.evaluation.views.TABLE_MODELS`) as trial objects.

    Each is scaled to metres and stood upright exactly as the single-view benchmark does
    (:func:`~mvbb_ros.evaluation.views.stand_on_table`: footprint centred on x = y = 0, bottom on
    z = 0 of its own frame); the trial then drops it and lets it settle.

    :param data_dir: the shared data folder (or its ``models`` folder).
    """
    from mvbb_ros.evaluation.views import stand_on_table, TABLE_MODELS  # noqa: PLC0415 (Open3D)

    models = _models_dir(data_dir)
    objects = []
    for model in TABLE_MODELS:
        mesh = stand_on_table(load_mesh(models / model.file), model)
        objects.append(
            _object_from_mesh(
                model.name,
                np.asarray(mesh.vertices),
                np.asarray(mesh.triangles),
                density,
                cache_dir,
            )
        )
    return objects


def mesh_folder_objects(
    folder: str | os.PathLike[str],
    units: Literal['m', 'mm', 'cm'],
    cache_dir: str | os.PathLike[str] | None = None,
    density: float = DEFAULT_DENSITY,
) -> list[PhysicsObject]:
    """
    Return every PLY/OBJ/STL mesh of `folder` (sorted by name) as a trial object.

    The vertices are multiplied by the metres per unit of `units` and keep their file's frame;
    concave meshes are decomposed by :func:`convex_parts`.

    :raises ValueError: for unknown units or a folder without meshes.
    """
    if units not in _UNITS:
        raise ValueError(f'units must be one of {sorted(_UNITS)}, got {units!r}')
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if not files:
        raise ValueError(f'no PLY/OBJ/STL mesh in {folder}')
    objects = []
    for file in files:
        mesh = load_mesh(file).remove_duplicated_vertices()  # STL stores a corner per triangle
        vertices = np.asarray(mesh.vertices, dtype=np.float64) * _UNITS[units]
        objects.append(
            _object_from_mesh(file.stem, vertices, np.asarray(mesh.triangles), density, cache_dir)
        )
    return objects
