"""
A virtual depth camera: pinhole depth images of triangle meshes by ray casting, with sensor noise.

Meshes are ray-cast from a pinhole camera (``open3d.t.geometry.RaycastingScene``), so a cloud is
a single partial view with realistic sensor noise (:class:`DepthNoise`), like the cloud of an
RGB-D camera. The command-line tools build their demo scenes on it
(:mod:`mvbb_ros.evaluation.synthetic`); the single-view benchmark renders the shared meshes with it
(:mod:`mvbb_ros.evaluation.views`).

Conventions:

* Lengths are in metres (any unit works as long as meshes, poses and noise agree).
* Camera optical frame (ROS ``*_optical_frame``): x right, y down, z forward. A camera pose is the
  4x4 transform T_world_camera, i.e. ``world = pose[:3, :3] @ camera + pose[:3, 3]``.
* Clouds are in the camera optical frame, float32, NaN where the ray hit nothing (or the sensor
  dropped the pixel).
* Label images hold the label of the mesh each pixel saw, and :data:`BACKGROUND` (-1) for no hit,
  for dropped pixels and for meshes labelled as background (a table).

Everything is deterministic for a given ``seed``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Protocol, runtime_checkable, TypeAlias

from mvbb_ros.arrays import BoolArray, cross, Float32Array, FloatArray, IntArray
import numpy as np
from numpy.typing import ArrayLike
import open3d as o3d

#: Label of pixels that saw no object: the table, nothing at all, or a dropped measurement.
BACKGROUND = -1

#: Default image size and intrinsics: a VGA RGB-D camera (Kinect / Xtion class), pixels.
DEFAULT_WIDTH = 640
DEFAULT_HEIGHT = 480
DEFAULT_FOCAL = 525.0

#: Pinhole intrinsics (fx, fy, cx, cy), pixels.
Intrinsics: TypeAlias = tuple[float, float, float, float]


# Sensor noise ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DepthNoise:
    """
    Noise model of a structured-light or stereo depth camera.

    Applied per valid pixel, in this order: grazing hits are dropped, random dropout, Gaussian
    depth noise along the pixel's ray, then optional disparity quantisation.

    :ivar sigma_const: constant part of the depth standard deviation, metres.
    :ivar sigma_quadratic: quadratic part, 1/metres: sigma(z) = sigma_const + sigma_quadratic *
        z^2 (about 1.3 mm at 0.8 m with the defaults, as for a Kinect-class sensor).
    :ivar disparity_step: quantisation step of the inverse depth 1/z, 1/metres; 0 turns it off.
        The depth step is then about disparity_step * z^2 (0.0029: Kinect v1's 2.9 mm at 1 m).
    :ivar max_incidence_deg: hits whose ray meets the surface more obliquely than this angle
        from the surface normal, degrees, return nothing, as on a real sensor.
    :ivar dropout: probability that any valid pixel is randomly lost, in [0, 1).
    """

    sigma_const: float = 0.0005
    sigma_quadratic: float = 0.0012
    disparity_step: float = 0.0
    max_incidence_deg: float = 80.0
    dropout: float = 0.0

    def __post_init__(self) -> None:
        if self.sigma_const < 0.0 or self.sigma_quadratic < 0.0 or self.disparity_step < 0.0:
            raise ValueError(f'DepthNoise terms must be >= 0, got {self}')
        if not 0.0 < self.max_incidence_deg <= 90.0:
            raise ValueError(f'max_incidence_deg must be in (0, 90], got {self.max_incidence_deg}')
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f'dropout must be in [0, 1), got {self.dropout}')

    def sigma(self, depth: ArrayLike) -> FloatArray:
        """Return the depth standard deviation (metres) at the given depths (metres)."""
        z = np.asarray(depth, dtype=np.float64)
        return self.sigma_const + self.sigma_quadratic * z * z


#: Default noise: Gaussian depth noise growing with z^2, grazing hits dropped, no quantisation.
DEFAULT_NOISE = DepthNoise()
#: A Kinect v1-like sensor: the default noise plus disparity quantisation and 1 % dropout.
KINECT_NOISE = DepthNoise(disparity_step=0.0029, dropout=0.01)


# Camera poses -----------------------------------------------------------------------------------


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> FloatArray:
    """
    Return the camera pose T_world_camera of an optical frame at `eye` looking at `target` (m).

    The optical z axis points at the target, x to the right of the image and y down, with the
    world direction `up` appearing upwards in the image.

    :raises ValueError: when eye and target coincide or the view direction is parallel to `up`.
    """
    eye_w = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye_w
    if np.linalg.norm(forward) < 1e-12:
        raise ValueError('look_at: eye and target coincide')
    forward /= np.linalg.norm(forward)
    right = cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError('look_at: view direction is parallel to the up vector')
    right /= np.linalg.norm(right)
    down = cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, forward])
    pose[:3, 3] = eye_w
    return pose


def orbit_pose(
    target: ArrayLike, distance: float, azimuth_deg: float, elevation_deg: float
) -> FloatArray:
    """
    Return a camera pose on a sphere around `target` (metres), looking at it.

    Azimuth is measured in the world x-y plane from +x towards +y, elevation up from that plane
    (both degrees). Azimuth 0 looks at the object's +x side (a mug's handle).
    """
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    center = np.asarray(target, dtype=np.float64)
    return look_at(center + distance * direction, center)


# Ray casting -------------------------------------------------------------------------------------


@runtime_checkable
class LabelledMeshes(Protocol):
    """Anything that lists its meshes with their labels (a scene of objects on a table)."""

    def labelled_meshes(self) -> list[tuple[int, o3d.geometry.TriangleMesh]]:
        """Return (label, world-frame mesh) pairs; :data:`BACKGROUND` for a table or a wall."""
        ...


#: What the camera can look at: labelled meshes, one mesh (label 0) or meshes labelled by index.
Meshes: TypeAlias = (
    LabelledMeshes | o3d.geometry.TriangleMesh | Sequence[o3d.geometry.TriangleMesh]
)


def _labelled(meshes: Meshes) -> list[tuple[int, o3d.geometry.TriangleMesh]]:
    if isinstance(meshes, LabelledMeshes):
        return list(meshes.labelled_meshes())
    if isinstance(meshes, o3d.geometry.TriangleMesh):
        return [(0, meshes)]
    return list(enumerate(meshes))


class DepthCamera:
    """
    A depth camera's world: a ray-casting scene over labelled meshes, rendered from any pose.

    Build it once and call :meth:`render` for many views (the scene is built only once).
    """

    def __init__(self, meshes: Meshes) -> None:
        """
        Prepare the meshes for ray casting.

        :param meshes: labelled meshes (:class:`LabelledMeshes`, e.g. a
            :class:`mvbb_ros.evaluation.synthetic.Scene`), one mesh (label 0) or a sequence of
            meshes (labelled by index), all in the world frame.
        :raises TypeError: when a mesh is not an Open3D ``TriangleMesh``.
        """
        self.scene = o3d.t.geometry.RaycastingScene()
        labels = {}
        for label, mesh in _labelled(meshes):
            if not isinstance(mesh, o3d.geometry.TriangleMesh):
                raise TypeError(f'expected open3d TriangleMesh, got {type(mesh).__name__}')
            geometry_id = self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
            labels[geometry_id] = label
        # Lookup table from geometry id to label; the last slot is for "no hit".
        self._lookup = np.full(max(labels, default=-1) + 2, BACKGROUND, dtype=np.int32)
        for geometry_id, label in labels.items():
            self._lookup[geometry_id] = label

    def render(
        self,
        camera_pose: ArrayLike,
        intrinsics: Intrinsics,
        size: tuple[int, int],
        noise: DepthNoise | None,
        rng: np.random.Generator,
        window: tuple[int, int, int, int] | None = None,
    ) -> tuple[Float32Array, IntArray]:
        """
        Render one organized depth image as points in the camera optical frame.

        :param camera_pose: (4, 4) T_world_camera of the optical frame (see :func:`look_at`).
        :param intrinsics: (fx, fy, cx, cy) in pixels (see :func:`camera_intrinsics`).
        :param size: (width, height) of the image, pixels.
        :param noise: the sensor model; None gives exact hits.
        :param rng: the random generator of the noise (used only with `noise`).
        :param window: only the pixels of columns ``[c0, c1)`` and rows ``[r0, r1)`` given as
            ``(c0, r0, c1, r1)`` (clipped to the image), for speed when the object of interest
            covers a small part of the image; None for the whole image. The noise drawn then
            differs from the whole image's.
        :return: ``(points, labels)``: (H, W, 3) float32 points (NaN without a measurement) and
            (H, W) int32 labels, of the window when one is given.
        :raises ValueError: when `camera_pose` is not 4x4.
        """
        pose = np.asarray(camera_pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f'camera_pose must be a 4x4 matrix, got shape {pose.shape}')
        fx, fy, cx, cy = intrinsics
        col0, row0, col1, row1 = (0, 0, *size) if window is None else window
        col0, col1 = max(col0, 0), min(col1, size[0])
        row0, row1 = max(row0, 0), min(row1, size[1])
        width, height = max(col1 - col0, 0), max(row1 - row0, 0)
        # Rays with unit z in the camera frame, so the hit distance t is the depth z.
        u = (np.arange(col0, col1, dtype=np.float64) - cx) / fx
        v = (np.arange(row0, row1, dtype=np.float64) - cy) / fy
        rays_cam = np.empty((height, width, 3))
        rays_cam[..., 0] = u[None, :]
        rays_cam[..., 1] = v[:, None]
        rays_cam[..., 2] = 1.0
        rays = np.empty((height, width, 6), dtype=np.float32)
        rays[..., :3] = pose[:3, 3]
        rays[..., 3:] = rays_cam @ pose[:3, :3].T
        hits = self.scene.cast_rays(o3d.core.Tensor(rays))
        depth = hits['t_hit'].numpy().astype(np.float64)
        ids = hits['geometry_ids'].numpy().astype(np.int64)
        valid = np.isfinite(depth)
        labels = self._lookup[np.where(valid, ids, len(self._lookup) - 1)]
        if noise is not None:
            valid &= self._keep(
                noise, hits['primitive_normals'].numpy(), rays[..., 3:], valid, rng
            )
            depth = self._noisy_depth(noise, depth, valid, rng)
            valid &= np.isfinite(depth) & (depth > 0.0)
        points = np.full((height, width, 3), np.nan, dtype=np.float32)
        points[valid] = rays_cam[valid] * depth[valid, None]
        labels[~valid] = BACKGROUND
        return points, labels

    @staticmethod
    def _keep(
        noise: DepthNoise,
        normals: Float32Array,
        directions: Float32Array,
        valid: BoolArray,
        rng: np.random.Generator,
    ) -> BoolArray:
        """Tell which valid pixels survive the incidence-angle cut-off and random dropout."""
        keep = np.zeros(valid.shape, dtype=bool)
        n, d = normals[valid].astype(np.float64), directions[valid].astype(np.float64)
        cos_incidence = np.abs(np.sum(n * d, axis=1)) / np.linalg.norm(d, axis=1)
        ok = cos_incidence >= math.cos(math.radians(noise.max_incidence_deg)) - 1e-12
        if noise.dropout > 0.0:
            ok &= rng.random(len(ok)) >= noise.dropout
        keep[valid] = ok
        return keep

    @staticmethod
    def _noisy_depth(
        noise: DepthNoise, depth: FloatArray, valid: BoolArray, rng: np.random.Generator
    ) -> FloatArray:
        out = depth.copy()
        z = depth[valid]
        z = z + rng.standard_normal(len(z)) * noise.sigma(z)
        if noise.disparity_step > 0.0:
            step = noise.disparity_step
            with np.errstate(divide='ignore'):
                z = 1.0 / (np.round(1.0 / (z * step)) * step)
        out[valid] = z
        return out


def image_window(
    points: ArrayLike,
    camera_pose: ArrayLike,
    intrinsics: Intrinsics,
    size: tuple[int, int],
    margin: int = 2,
) -> tuple[int, int, int, int]:
    """
    Return the pixel window ``(c0, r0, c1, r1)`` that sees every given world point.

    For :meth:`DepthCamera.render`: pass the corners of an object's bounding box to render only
    the pixels that can see it. Points behind the camera give the whole image.

    :param points: (N, 3) world points.
    :param camera_pose: (4, 4) T_world_camera.
    :param intrinsics: (fx, fy, cx, cy), pixels.
    :param size: (width, height) of the image.
    :param margin: pixels added on every side.
    """
    pose = np.asarray(camera_pose, dtype=np.float64)
    local = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - pose[:3, 3]) @ pose[:3, :3]
    if len(local) == 0 or np.any(local[:, 2] <= 1e-9):
        return 0, 0, size[0], size[1]
    fx, fy, cx, cy = intrinsics
    cols = fx * local[:, 0] / local[:, 2] + cx
    rows = fy * local[:, 1] / local[:, 2] + cy
    return (
        max(int(math.floor(cols.min())) - margin, 0),
        max(int(math.floor(rows.min())) - margin, 0),
        min(int(math.ceil(cols.max())) + margin + 1, size[0]),
        min(int(math.ceil(rows.max())) + margin + 1, size[1]),
    )


def camera_intrinsics(
    width: int,
    height: int,
    fx: float = DEFAULT_FOCAL,
    fy: float = DEFAULT_FOCAL,
    cx: float | None = None,
    cy: float | None = None,
) -> Intrinsics:
    """
    Return checked pinhole intrinsics (fx, fy, cx, cy); the principal point defaults to centre.

    :raises ValueError: for a non-positive image size or focal length.
    """
    if width < 1 or height < 1:
        raise ValueError(f'image size must be positive, got {width}x{height}')
    if fx <= 0.0 or fy <= 0.0:
        raise ValueError(f'focal lengths must be positive, got fx={fx}, fy={fy}')
    return (
        float(fx),
        float(fy),
        (width - 1) / 2.0 if cx is None else float(cx),
        (height - 1) / 2.0 if cy is None else float(cy),
    )


def render_depth_cloud(
    meshes: Meshes,
    camera_pose: ArrayLike,
    *,
    width: int = DEFAULT_WIDTH,
    height: int = DEFAULT_HEIGHT,
    fx: float = DEFAULT_FOCAL,
    fy: float = DEFAULT_FOCAL,
    cx: float | None = None,
    cy: float | None = None,
    noise: DepthNoise | None = DEFAULT_NOISE,
    seed: int = 0,
    organized: bool = True,
) -> tuple[Float32Array, IntArray]:
    """
    Ray-cast a depth camera image of meshes into a point cloud in the camera optical frame.

    Pixel (u, v) looks along ((u - cx) / fx, (v - cy) / fy, 1) in the camera frame (pixel
    centres at integer coordinates, as in OpenCV and ROS CameraInfo).

    :param meshes: labelled meshes (a :class:`mvbb_ros.evaluation.synthetic.Scene`: objects
        labelled by index, the table :data:`BACKGROUND`), one mesh (label 0) or a sequence of
        meshes (labelled by index), all in the world frame (metres).
    :param camera_pose: (4, 4) T_world_camera of the optical frame (see :func:`look_at`).
    :param width: image width, pixels.
    :param height: image height, pixels.
    :param fx: horizontal focal length, pixels.
    :param fy: vertical focal length, pixels.
    :param cx: principal point column, pixels; None for the image centre (width - 1) / 2.
    :param cy: principal point row, pixels; None for the image centre (height - 1) / 2.
    :param noise: the sensor model; None gives exact hits (no noise, no dropped pixels).
    :param seed: seed of the noise.
    :param organized: True for (H, W, 3) points and (H, W) labels; False for the valid points
        only, (N, 3) and (N,) in row-major pixel order.
    :return: ``(points, labels)``: float32 points in metres in the camera optical frame (NaN
        where a pixel has no measurement) and int32 labels (:data:`BACKGROUND` for the table and
        for pixels without a measurement).
    """
    intrinsics = camera_intrinsics(width, height, fx, fy, cx, cy)
    points, labels = DepthCamera(meshes).render(
        camera_pose, intrinsics, (width, height), noise, np.random.default_rng(seed)
    )
    if organized:
        return points, labels
    valid = np.isfinite(points[..., 2])
    return points[valid], labels[valid]
