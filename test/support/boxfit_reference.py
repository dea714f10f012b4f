"""
A slow, near-exact minimum-volume box and a generator of varied clouds, for the box fit's tests.

The reference (:func:`reference_box`) hulls every point (no coreset) and turns the box to its
best rotation about every facet normal, every plane normal of two of the 80 longest hull edges
and 2,000 evenly spread directions, then walks the best 24 axes on the sphere with a shrinking
pattern search (steps from 3 degrees down to 1e-6 radians, each of the box's three axes as the
pivot) until no step gains. A minimal box has a face flush with a hull facet, or two faces
flush with hull edges (O'Rourke 1985): the first set holds the former exactly, the pattern
search converges on the latter. It costs seconds per dense cloud; the package's fit is
compared to it in ``test/geometry/boxfit/test_quality.py`` and ``benchmarks/boxfit_quality.py``.

:func:`varied_clouds` draws clouds of three kinds from the shared data, seeded:

* ``scan``: a shared real scan, rotated at random, cut by zero to two random half-spaces
  (each keeping 40 to 90 % of the points) and sub-sampled to 150 up to 40,000 points;
* ``dense``: a bunny range scan resampled (with replacement, 0.2 mm noise) to 30,000 to
  40,000 points and rotated: the dense range scans the coresets are for;
* ``view``: a random partial view of a shared mesh (scaled to 0.25 m), ray-cast by the
  package's depth camera with its noise from 0.5 to 0.9 m, sub-sampled to 150 up to all points.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
import math
from pathlib import Path

from mvbb_ros.geometry.boxfit.hull import convex_hull
from mvbb_ros.geometry.boxfit.search import copy_frame, edge_pair_axes, longest_edges
from mvbb_ros.geometry.boxfit.turn import new_work, rotate_about
import numba as nb
import numpy as np
from scipy.spatial.transform import Rotation

#: Sizes of the reference's candidate sets and pattern search.
DIRECTIONS = 2000
PAIR_EDGES = 80
STARTS = 24
KINDS = ('scan', 'dense', 'view')


@nb.njit
def _fibonacci_half_sphere(count: int) -> np.ndarray:
    """Return `count` unit directions evenly spread over the upper half sphere."""
    out = np.empty((count, 3))
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for i in range(count):
        z = 1.0 - (i + 0.5) / count
        r = math.sqrt(max(0.0, 1.0 - z * z))
        out[i, 0] = r * math.cos(golden * i)
        out[i, 1] = r * math.sin(golden * i)
        out[i, 2] = z
    return out


@nb.njit
def _walk(vertices, work, frame, volume):
    """Pattern search of the box's first axis on the sphere, each axis in turn the pivot."""
    trial = np.empty((3, 3))
    best_frame = frame.copy()
    for _ in range(20):
        start_volume = volume
        # The pivot: the frame's axis whose best rotation is smallest.
        for column in (1, 2):
            found = rotate_about(
                vertices,
                work,
                best_frame[0, column],
                best_frame[1, column],
                best_frame[2, column],
                trial,
            )
            if found < volume:
                volume = found
                copy_frame(trial, best_frame)
        step = 0.05
        while step > 1e-6:
            moved = False
            ax, ay, az = best_frame[0, 0], best_frame[1, 0], best_frame[2, 0]
            for d in range(8):
                angle = d * math.pi / 4.0
                c = math.cos(angle) * step
                s = math.sin(angle) * step
                x = ax + c * best_frame[0, 1] + s * best_frame[0, 2]
                y = ay + c * best_frame[1, 1] + s * best_frame[1, 2]
                z = az + c * best_frame[2, 1] + s * best_frame[2, 2]
                norm = math.sqrt(x * x + y * y + z * z)
                found = rotate_about(vertices, work, x / norm, y / norm, z / norm, trial)
                if found < volume * (1.0 - 1e-12):
                    volume = found
                    copy_frame(trial, best_frame)
                    moved = True
                    break
            if not moved:
                step *= 0.5
        if not volume < start_volume * (1.0 - 1e-12):
            break
    return volume, best_frame


@nb.njit
def _reference_search(vertices, normals, edges, edge_facets, extra, starts):
    """Return the volume and frame of the smallest box found (see the module notes)."""
    work = new_work(vertices, normals, edges, edge_facets)
    count = normals.shape[0] + extra.shape[0]
    volumes = np.empty(count)
    frames = np.empty((count, 3, 3))
    for j in range(count):
        axis = normals[j] if j < normals.shape[0] else extra[j - normals.shape[0]]
        volumes[j] = rotate_about(vertices, work, axis[0], axis[1], axis[2], frames[j])
    order = np.argsort(volumes)
    best_volume = np.inf
    best_frame = np.eye(3)
    for i in range(min(starts, count)):
        volume, frame = _walk(vertices, work, frames[order[i]].copy(), volumes[order[i]])
        if volume < best_volume:
            best_volume = volume
            best_frame = frame
    return best_volume, best_frame


@dataclass(frozen=True)
class ReferenceBox:
    """The reference's box: its volume (units of the points cubed) and rotation (columns)."""

    volume: float
    rotation: np.ndarray


def reference_box(points: np.ndarray) -> ReferenceBox:
    """
    Return the near-exact minimum-volume box of full-dimensional points (see the module notes).

    :param points: (N, 3) finite points spanning three dimensions.
    """
    pts = np.asarray(points, dtype=np.float64)
    low, high = pts.min(axis=0), pts.max(axis=0)
    scale = 0.5 * float((high - low).max())
    local = np.ascontiguousarray((pts - 0.5 * (low + high)) / scale)
    hull = convex_hull(local)
    if hull.status != 3:
        raise ValueError(
            f'the reference needs full-dimensional points (hull status {hull.status})'
        )
    vertices = np.ascontiguousarray(local[hull.vertices])
    extra = np.concatenate(
        [
            np.eye(3),
            _fibonacci_half_sphere(DIRECTIONS),
            edge_pair_axes(vertices, hull.edges, longest_edges(vertices, hull.edges, PAIR_EDGES)),
        ]
    )
    _, frame = _reference_search(
        vertices, hull.normals, hull.edges, hull.edge_facets, np.ascontiguousarray(extra), STARTS
    )
    # The box of every point in the found frame (the hull's box, up to the hull's tolerance).
    spans = np.ptp(local @ frame, axis=0)
    return ReferenceBox(float(np.prod(spans)) * scale**3, frame)


# Varied clouds ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cloud:
    """A generated cloud: its kind (:data:`KINDS`), a name saying how it was made, its points."""

    kind: str
    name: str
    points: np.ndarray


def _rotated(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return the points turned by a random rotation about their centroid, moved at random."""
    rotation = Rotation.random(random_state=rng).as_matrix()
    centre = points.mean(axis=0)
    return (points - centre) @ rotation.T + rng.uniform(-1.0, 1.0, 3)


def _cropped(points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """Return the points cut by zero to two random half-spaces, and how many cuts."""
    cuts = int(rng.integers(0, 3))
    for _ in range(cuts):
        normal = rng.normal(size=3)
        heights = points @ (normal / np.linalg.norm(normal))
        points = points[heights <= np.quantile(heights, rng.uniform(0.4, 0.9))]
    return points, cuts


def _subsampled(points: np.ndarray, rng: np.random.Generator, low: int, high: int) -> np.ndarray:
    """Return a random subset of log-uniform size in [low, high] (all points when fewer)."""
    high = min(high, len(points))
    if high <= low:
        return points
    size = int(round(math.exp(rng.uniform(math.log(low), math.log(high)))))
    return points[np.sort(rng.choice(len(points), size, replace=False))]


class _Views:
    """Ray-cast partial views of the shared meshes, each mesh scaled to 0.25 m (lazy)."""

    def __init__(self, models: Path) -> None:
        self.paths = sorted(models.glob('*_mesh.ply')) + sorted(models.glob('*_zipper.ply'))
        self.cameras: dict[Path, object] = {}

    def render(self, rng: np.random.Generator) -> tuple[str, np.ndarray]:
        import open3d as o3d

        from mvbb_ros.evaluation.camera import (
            camera_intrinsics,
            DEFAULT_NOISE,
            DepthCamera,
            look_at,
        )

        path = self.paths[int(rng.integers(len(self.paths)))]
        if path not in self.cameras:
            mesh = o3d.io.read_triangle_mesh(str(path))
            vertices = np.asarray(mesh.vertices)
            low, high = vertices.min(axis=0), vertices.max(axis=0)
            mesh.translate(-0.5 * (low + high))
            mesh.scale(0.25 / float(np.linalg.norm(high - low)), center=(0.0, 0.0, 0.0))
            self.cameras[path] = DepthCamera(mesh)
        camera = self.cameras[path]
        for _ in range(20):
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            up = rng.normal(size=3)
            if abs(float(up @ direction)) > 0.99 * float(np.linalg.norm(up)):
                continue
            pose = look_at(direction * rng.uniform(0.5, 0.9), np.zeros(3), up)
            frame, _ = camera.render(  # type: ignore[attr-defined]
                pose, camera_intrinsics(640, 480, 525.0, 525.0), (640, 480), DEFAULT_NOISE, rng
            )
            points = frame.reshape(-1, 3).astype(np.float64)
            points = points[np.isfinite(points).all(axis=1)]
            if len(points) >= 200:
                return path.stem, points
        raise RuntimeError(f'no view of {path} with 200 points in 20 tries')


def varied_clouds(
    count: int,
    seed: int,
    data: Path,
    *,
    kinds: tuple[str, ...] = KINDS,
    max_points: int = 40_000,
) -> Iterator[Cloud]:
    """
    Yield `count` varied clouds (see the module notes), kinds taken in turn, from `seed`.

    :param data: the shared data folder (``scans/``, ``models/``).
    :param kinds: the kinds drawn, in turn.
    :param max_points: the most points of a ``scan`` or ``view`` cloud (``dense`` ignores it).
    """
    rng = np.random.default_rng(seed)
    scans = {path.stem: path for path in sorted((data / 'scans').glob('*.npy'))}
    bunnies = [name for name in scans if name.startswith('bunny_rangescan')]
    loaded: dict[str, np.ndarray] = {}
    views = _Views(data / 'models')

    def scan(name: str) -> np.ndarray:
        if name not in loaded:
            loaded[name] = np.load(scans[name]).astype(np.float64)
        return loaded[name]

    for number in range(count):
        kind = kinds[number % len(kinds)]
        if kind == 'scan':
            name = list(scans)[int(rng.integers(len(scans)))]
            points, cuts = _cropped(_rotated(scan(name), rng), rng)
            points = _subsampled(points, rng, 150, max_points)
            label = f'{name} cut {cuts}'
        elif kind == 'dense':
            name = bunnies[int(rng.integers(len(bunnies)))]
            base = scan(name)
            size = int(rng.integers(30_000, 40_001))
            points = base[rng.integers(0, len(base), size)] + rng.normal(
                scale=2e-4, size=(size, 3)
            )
            points = _rotated(points, rng)
            label = f'{name} resampled'
        elif kind == 'view':
            name, points = views.render(rng)
            points = _subsampled(points, rng, 150, max_points)
            label = f'{name} view'
        else:
            raise ValueError(f'unknown kind {kind!r}; known: {KINDS}')
        yield Cloud(kind, f'{number} {label} ({len(points)} points)', np.ascontiguousarray(points))
