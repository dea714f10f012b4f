"""
The hidden side of a single sensor view: what the sensor could not see is not empty space.

A segmented cloud from one viewpoint holds the object's near side only. Fitted as it is, boxes
hug that skin and the fit-and-split gain Theta* carves it into plates of sensor thickness,
because the object's hidden inside counts as empty space. :func:`complete_view` therefore turns
the observed points into a *solid*: the observed points, an estimate of the far side, and
samples of the space between them along the sensor's rays (space that was never seen to be
free). The decomposition then runs on the solid with the paper's gain.

Methods (``Completion``):

* ``'mirror'``: the far side is the near side mirrored about a plane (Bohg et al., "Mind the
  Gap", ICRA 2011). The plane is found by :func:`find_mirror_plane`: among candidate planes, the
  one whose mirror image contradicts the view least (a mirrored point the sensor would have
  seen, in front of a seen surface or where it saw past the object), then the nearest to the
  sensor. With an up direction the planes are vertical (the object stands on a support) and
  the solid is also filled straight down to its lowest point; without one, planes turned up to
  35 degrees from the viewing direction are tried. A view that shows one flat face (a plate:
  :data:`PLATE_RATIO`) is extruded instead: nothing in it says how deep the object is, and a
  vertical mirror would stand a leaning screen up as a tent.
* ``'extrude'``: every observed point is extended away from the viewpoint until it leaves the
  observed points' minimum box.
* ``'none'``: the observed points alone (the paper).

The mirror plane's search is :mod:`~mvbb_ros.geometry.views.mirror`, the samples of the space
between the seen surface and the far side :mod:`~mvbb_ros.geometry.views.fill`, both on the
view's raster (:mod:`~mvbb_ros.geometry.views.raster`); their hot loops (rasterising, testing
mirror planes, sampling rays) are numba kernels. ``docs/single_views.md`` describes the methods
and what they measure on real scans and virtual views.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import get_args, Literal

from mvbb_ros.arrays import cross, FloatArray
from mvbb_ros.common.workers import Workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
from mvbb_ros.geometry.views.fill import (
    fill_down,
    fill_to_box,
    fill_to_far_side,
    one_per_cell,
    SOLID_CELLS,
)
from mvbb_ros.geometry.views.mirror import find_mirror_plane, MirrorPlane
from mvbb_ros.geometry.views.raster import behind_others, view_raster
import numpy as np
from numpy.typing import ArrayLike


#: How the hidden side is estimated (the ``shape_completion`` setting); see the module doc.
Completion = Literal['none', 'mirror', 'extrude']
COMPLETIONS: tuple[Completion, ...] = get_args(Completion)

#: A cloud with more than this share of its points behind another surface along their ray
#: (:func:`behind_others`), seen from the viewpoint, is not one sensor view (a model, merged
#: views, or a wrong viewpoint): its points are used as they are.
MAX_SELF_HIDDEN = 0.18
#: A jump in range of more than this many point spacings along a ray separates two surfaces.
SURFACE_GAP = 3.0
#: A view whose observed points' box is at most this thin for its middle extent shows one flat
#: face (a screen, a board, a book): it is completed by extrusion to that box, not mirrored.
#: Measured on the shared scans and views: the Kinect laptop's leaning screen 0.073, a flat mOSD
#: object 0.109, then nothing under 0.25 (``docs/single_views.md``).
PLATE_RATIO = 0.15


@dataclass(frozen=True, eq=False)
class CompletedView:
    """
    One object's observed points and the estimate of what the sensor could not see.

    :ivar points: (M, 3) the solid: the observed points first, then the estimated ones.
    :ivar observed: how many of :attr:`points` the sensor saw.
    :ivar method: the completion asked for.
    :ivar plane: the mirror plane (``'mirror'``, unless the view was a plate), else None.
    :ivar skipped: why nothing was estimated although a completion was asked for, else None.
    """

    points: FloatArray
    observed: int
    method: Completion
    plane: MirrorPlane | None = None
    skipped: str | None = None

    @property
    def estimated(self) -> FloatArray:
        """Return the estimated points (the solid without the observed ones)."""
        start = self.observed
        return self.points[start:]


def complete_view(
    points: ArrayLike,
    *,
    method: Completion = 'none',
    viewpoint: ArrayLike = (0.0, 0.0, 0.0),
    up: ArrayLike | None = None,
    spacing: float,
    floor: float | None = None,
    pool: Workers | None = None,
) -> CompletedView:
    """
    Return one object's observed points with an estimate of what the sensor could not see.

    :param points: (N, 3) observed points of one object, metres, N >= 1.
    :param method: ``'none'``, ``'mirror'`` or ``'extrude'`` (see the module doc).
    :param viewpoint: (3,) sensor position in the points' frame (the frame's origin for camera
        and laser frames).
    :param up: up direction in the points' frame (need not be unit), or None when unknown.
    :param spacing: point spacing (the voxel size), metres: the step of the samples.
    :param floor: with `up`, the height along unit `up` of the support the object rests on
        (metres), or None: the hidden side is filled down to it, not only to the lowest
        observed point, and no estimate goes below it (the table ends the object).
    :param pool: workers: the observed points' box is fitted while the view is rastered (the
        same solid with any), or None.
    :return: the solid, observed points first.
    :raises ValueError: for an unknown method or a non-positive spacing.
    """
    if method not in COMPLETIONS:
        raise ValueError(f'completion must be one of {COMPLETIONS}, got {method!r}')
    if not spacing > 0.0:
        raise ValueError(f'spacing must be > 0, got {spacing!r}')
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    eye = np.asarray(viewpoint, dtype=np.float64)
    if method == 'none' or len(pts) < 4:
        return CompletedView(pts, len(pts), method)
    fitted = None if pool is None else pool.submit(lambda: minimum_bounding_box(pts))
    raster = view_raster(pts, eye, spacing)
    self_hidden = float(np.mean(behind_others(pts, raster, SURFACE_GAP * spacing)))
    if self_hidden > MAX_SELF_HIDDEN:
        reason = (
            f'not one view from {eye.tolist()}: {100 * self_hidden:.0f} % of the points lie '
            'behind others (is viewpoint the sensor position in the cloud frame?)'
        )
        if fitted is not None:
            fitted.cancel()
        return CompletedView(pts, len(pts), method, skipped=reason)
    # The observed points' minimum box: the extrusion stops at its far faces, and its axes are
    # the object's likely symmetry directions.
    box = minimum_bounding_box(pts) if fitted is None else fitted.result()
    thin, middle = np.sort(box.extents)[:2]
    if method == 'extrude' or thin <= PLATE_RATIO * middle:
        # One flat face seen gives no depth behind it, and a mirror about a vertical plane
        # would stand a leaning plate up as a tent: a plate keeps its own box.
        estimated = fill_to_box(pts, eye, box, spacing)
        every = np.ones(len(estimated), dtype=np.bool_)
        estimated = estimated[one_per_cell(estimated, every, SOLID_CELLS * spacing)]
        return CompletedView(np.concatenate([pts, estimated]), len(pts), method)
    unit_up = None
    if up is not None:
        unit_up = np.asarray(up, dtype=np.float64)
        unit_up = unit_up / np.linalg.norm(unit_up)
    plane = find_mirror_plane(
        pts, raster, axes=box.rotation.T, up=unit_up, spacing=spacing, pool=pool
    )
    # Keep the mirror images that add something: hidden behind the seen surface. The others
    # either repeat a seen surface or contradict the view.
    far = plane.mirror(pts)
    far = far[raster.hidden(far, spacing)]
    # The space between the seen surface and its mirror image, within the box of the two: rays
    # at the outline must not carry the far side's range past the object's sides.
    both = np.concatenate([pts, far])
    bounds = Box.enclosing(both, box.rotation)
    fill = fill_to_far_side(pts, far, raster, spacing)
    fill = fill[bounds.contains(fill, tol=spacing)]
    if unit_up is not None:
        # Nor past the seen width across the (vertical) mirror plane: a mirror keeps that
        # width, but the rays diverge from the viewpoint, so the samples behind the edge of the
        # seen surface run wider than it, into the box's slack (a 3 cm plate seen end-on from
        # 0.5 m came out 1 cm thicker, 1.7 times its volume). The slack stays along the normal
        # and up, where the far side and the bottom are estimates that tend to fall short.
        side = cross(unit_up, plane.normal)
        across = fill @ side
        width = both @ side
        fill = fill[(across >= width.min()) & (across <= width.max())]
    parts = [both, fill]
    if unit_up is not None:
        lowest = float(np.min(both @ unit_up)) if floor is None else floor
        parts.append(fill_down(np.concatenate(parts), unit_up, lowest, spacing))
    estimated = np.concatenate(parts[1:])
    if unit_up is not None and floor is not None:
        keep = estimated @ unit_up >= floor
    else:
        keep = np.ones(len(estimated), dtype=np.bool_)
    # The cells of the kept points only, their indices into `estimated`: one copy, not two.
    estimated = estimated[one_per_cell(estimated, keep, SOLID_CELLS * spacing)]
    return CompletedView(np.concatenate([pts, estimated]), len(pts), method, plane)
