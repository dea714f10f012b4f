"""
Pictures of points, boxes and grasps with matplotlib (Agg only, headless, no pyplot state).

Each panel (one cloud with its boxes and grasps) is drawn as one row of orthographic views. The
views are taken in a frame of the panel's points: by default the axes of their minimum-volume box,
longest (a) first, shortest (c) last, so 'top' looks down c onto the a-b face, 'front' looks along
b and 'side' along a (the object's own box seen face-on); 'iso' is an oblique view. All views of a
row share one scale and have an equal aspect ratio, so boxes look like boxes. Points are shaded
by depth (nearer is darker), box edges hidden behind their own box are dashed, and each row has a
legend with the box sizes and a scale bar in every view.

A grasp is drawn as a parallel-jaw gripper seen from the side: its fingertips at
``position +- width / 2 * closing``, fingers and palm behind them (against ``approach``) and a
stem; the best (first) grasp in red.

Files are written atomically (:func:`mvbb_ros.common.atomic.atomic_path`): a reader never sees
a half written picture and a failure leaves an existing file untouched.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import itertools
import math
import os
from pathlib import Path
import typing
from typing import Any

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure, SubFigure
from matplotlib.lines import Line2D
from matplotlib.text import Annotation
from mvbb_ros.arrays import cross, perpendicular_axes
from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.geometry.box import EDGES
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
import numpy as np
from numpy.typing import ArrayLike, NDArray

if typing.TYPE_CHECKING:  # Box is only needed for annotations (and ruff and flake8 disagree on
    from mvbb_ros.geometry.box import Box  # the order of 'Box, EDGES' in one import)

FloatArray = NDArray[np.float64]

#: Named views as (elevation, azimuth) in degrees in the view frame, as for matplotlib 3D axes.
NAMED_VIEWS: dict[str, tuple[float, float]] = {
    'top': (90.0, -90.0),
    'front': (0.0, -90.0),
    'side': (0.0, 0.0),
    'iso': (28.0, -58.0),
    # With frame='data' and a cloud in a camera optical frame (x right, y down, z forward):
    # the camera's own view.
    'camera': (-90.0, -90.0),
}
DEFAULT_VIEWS: tuple[str, ...] = ('top', 'front', 'side')
#: View frames by name (see :func:`render_panels`); the first is the default.
FRAMES: tuple[str, ...] = ('box', 'principal', 'data')

#: Box colours: tab10 without its red (kept for the best grasp) and grey (the points), then more.
BOX_COLORS: tuple[str, ...] = (
    '#1f77b4',
    '#ff7f0e',
    '#2ca02c',
    '#9467bd',
    '#8c564b',
    '#e377c2',
    '#bcbd22',
    '#17becf',
    '#393b79',
    '#e7ba52',
    '#637939',
    '#843c39',
)
BEST_GRASP_COLOR = '#d62728'
GRASP_COLOR = '#202020'

View = str | tuple[float, float]

# Corner i of Box.corners() has these signs along the box axes (see Box.corners).
_CORNER_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
_LEGEND_WIDTH = 2.4  # inches
_ROW_HEADER = 0.45  # inches above the views of a row, for its title
_LEGEND_ROWS = 16  # more boxes than this: two legend columns of names without sizes


@dataclass(frozen=True)
class Panel:
    """
    One row of a picture: a cloud with its boxes and, optionally, grasps.

    :ivar points: (N, 3) or organized (H, W, 3) points; non-finite points are ignored.
    :ivar boxes: the boxes, drawn as wireframes in distinct colours.
    :ivar grasps: grasps, best first; each needs ``.position`` (3,), ``.approach`` (3,) unit
        direction the hand moves in, ``.closing`` (3,) unit direction the fingers close along,
        and ``.width`` (opening, in the points' unit).
    :ivar title: the row title, e.g. 't = 0.94: 4 boxes'.
    """

    points: ArrayLike
    boxes: Sequence[Box] = ()
    grasps: Sequence[Any] | None = None
    title: str = ''


def render_boxes(
    path: str | os.PathLike[str],
    points: ArrayLike,
    boxes: Sequence[Box],
    *,
    grasps: Sequence[Any] | None = None,
    title: str = '',
    **options: Any,
) -> Path:
    """
    Draw one cloud with its boxes (and grasps) from several views into an image file.

    This is a one-panel :func:`render_panels`; `options` are its keyword arguments (views,
    frame, max_points, point_size, max_grasps, unit, panel_size, dpi).

    :return: the path written.
    """
    panel = Panel(points=points, boxes=tuple(boxes), grasps=grasps, title=title)
    return render_panels(path, [panel], **options)


def render_panels(
    path: str | os.PathLike[str],
    panels: Sequence[Panel],
    *,
    views: Sequence[View] = DEFAULT_VIEWS,
    frame: str | ArrayLike = 'box',
    max_points: int = 20_000,
    point_size: float | None = None,
    max_grasps: int = 8,
    unit: str = 'm',
    title: str = '',
    panel_size: float = 3.0,
    dpi: int = 110,
) -> Path:
    """
    Draw several decompositions, one row per panel and one column per view, into an image file.

    :param path: output file; its extension picks the format (png, svg, pdf, ...; none: png).
    :param panels: the rows.
    :param views: names from :data:`NAMED_VIEWS` or (elevation, azimuth) pairs in degrees.
    :param frame: 'box' (axes of the minimum-volume box of each panel's points, longest
        first), 'principal' (their principal axes, largest spread first), 'data' (the points'
        own axes: 'top' then looks at the x-y plane; 'camera' is a camera-frame cloud's own
        view) or a (3, 3) rotation whose columns are the view frame's axes in data coordinates.
    :param max_points: at most this many points are drawn per panel (a fixed-seed subset).
    :param point_size: marker area in points^2; None picks one from the number of points.
    :param max_grasps: at most this many grasps are drawn per panel (the first, best ones).
    :param unit: length unit of the coordinates, for scale bars and box sizes ('m' shows cm).
    :param title: figure title above all rows.
    :param panel_size: size of one view, inches.
    :param dpi: resolution, dots per inch.
    :return: the path written.
    :raises ValueError: for no panels or views, an unknown view, frame or image format, or
        points of the wrong shape.
    """
    if not panels:
        raise ValueError('render_panels needs at least one panel')
    if not views:
        raise ValueError('render_panels needs at least one view')
    view_angles = [_view_angles(view) for view in views]
    target = Path(path)
    fmt = target.suffix.lstrip('.').lower() or 'png'
    fig = Figure(dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    if fmt not in canvas.get_supported_filetypes():
        raise ValueError(f'cannot write {target}: unsupported image format {fmt!r}')

    title_height = 0.45 if title else 0.0
    row_height = panel_size + _ROW_HEADER
    width = len(views) * panel_size + _LEGEND_WIDTH
    fig.set_size_inches(width, len(panels) * row_height + title_height)
    if title:
        fig.suptitle(title, fontsize=13, fontweight='bold', y=1.0 - 0.12 / fig.get_figheight())
    heights = ([title_height] if title else []) + [row_height] * len(panels)
    rows = fig.subfigures(len(heights), 1, squeeze=False, height_ratios=heights).ravel()
    skip = len(heights) - len(panels)  # the title row
    rows = rows[skip:]
    for subfig, panel in zip(rows, panels, strict=True):
        _draw_panel(
            subfig,
            panel,
            views=list(views),
            view_angles=view_angles,
            frame=frame,
            max_points=max_points,
            point_size=point_size,
            max_grasps=max_grasps,
            unit=unit,
            layout=(len(views) * panel_size / width, 1.0 - _ROW_HEADER / row_height),
        )
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi, facecolor='white')
    return target


# Geometry ---------------------------------------------------------------------------------------


def _view_angles(view: View) -> tuple[float, float]:
    if isinstance(view, str):
        if view not in NAMED_VIEWS:
            raise ValueError(f'unknown view {view!r}; expected one of {sorted(NAMED_VIEWS)}')
        return NAMED_VIEWS[view]
    elevation, azimuth = (float(v) for v in view)
    return elevation, azimuth


def _view_rotation(elevation_deg: float, azimuth_deg: float) -> FloatArray:
    """Return rows screen-right, screen-up and towards-the-viewer, in view-frame coordinates."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    towards = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.array([-math.sin(az), math.cos(az), 0.0])
    return np.stack([right, cross(towards, right), towards])


def _frame_rotation(
    frame: str | ArrayLike, points: FloatArray, boxes: Sequence[Box]
) -> FloatArray:
    """Return the view frame's axes (columns) in data coordinates."""
    if not isinstance(frame, str):
        rotation = np.asarray(frame, dtype=np.float64)
        if rotation.shape != (3, 3) or not np.allclose(
            rotation.T @ rotation, np.eye(3), atol=1e-6
        ):
            raise ValueError('frame rotation must be an orthonormal 3x3 matrix')
        return rotation
    if frame not in FRAMES:
        raise ValueError(f'frame must be one of {FRAMES} or a 3x3 rotation, got {frame!r}')
    sample = _subsample(points, 5000) if len(points) >= 4 else _box_corners(boxes)
    if frame == 'data' or len(sample) < 2:
        return np.eye(3)
    if frame == 'box':
        box = minimum_bounding_box(sample)
        axes = box.rotation[:, np.argsort(-box.extents, kind='stable')]
    else:
        centered = sample - sample.mean(axis=0)
        _, vectors = np.linalg.eigh(centered.T @ centered)
        axes = vectors[:, ::-1]  # largest spread first
    axes = axes.copy()
    for k in range(2):  # deterministic signs: each axis's largest component positive
        if axes[np.argmax(np.abs(axes[:, k])), k] < 0.0:
            axes[:, k] = -axes[:, k]
    axes[:, 2] = cross(axes[:, 0], axes[:, 1])
    return axes


def ground_frame(up: ArrayLike, viewpoint: ArrayLike, points: ArrayLike) -> FloatArray:
    """
    Return a view frame standing on the ground: its third axis `up`, its second the sensor's.

    The columns are (right, forward, up) in data coordinates: forward is the direction from
    `viewpoint` to the points' centroid, made horizontal (any horizontal direction when the
    sensor looks straight down). With it, 'top' looks down onto the table and 'front' looks
    from the sensor's side; the axes do not depend on the points' own extents, so two pictures
    of nearly the same scene keep their orientation.

    :param up: (3,) the up direction (need not be unit).
    :param viewpoint: (3,) the sensor position.
    :param points: (N, 3) the points drawn, N >= 1.
    """
    third = np.asarray(up, dtype=np.float64)
    third = third / np.linalg.norm(third)
    centre = np.asarray(points, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    forward = centre - np.asarray(viewpoint, dtype=np.float64)
    forward = forward - (forward @ third) * third
    length = float(np.linalg.norm(forward))
    if length <= 1e-9 * max(1.0, float(np.linalg.norm(centre))):
        forward = perpendicular_axes(third)[0]
    else:
        forward = forward / length
    return np.column_stack([cross(forward, third), forward, third])


def _box_corners(boxes: Sequence[Box]) -> FloatArray:
    if not boxes:
        return np.zeros((0, 3))
    return np.concatenate([box.corners() for box in boxes])


def _finite_points(points: ArrayLike) -> FloatArray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.size == 0:
        return np.zeros((0, 3))
    if pts.ndim not in (2, 3) or pts.shape[-1] != 3:
        raise ValueError(f'points must have shape (N, 3) or (H, W, 3), got {pts.shape}')
    pts = pts.reshape(-1, 3)
    return pts[np.all(np.isfinite(pts), axis=1)]


def _subsample(points: FloatArray, max_points: int) -> FloatArray:
    if len(points) <= max_points:
        return points
    keep = np.random.default_rng(0).choice(len(points), size=max(max_points, 0), replace=False)
    return points[np.sort(keep)]


def _gripper_glyphs(grasps: Sequence[Any], finger: float) -> list[FloatArray]:
    """Return each grasp as a polyline (7, 3): tip, palm, palm, tip, a break (NaN), the stem."""
    glyphs = []
    for grasp in grasps:
        position = np.asarray(grasp.position, dtype=np.float64).reshape(3)
        approach = np.asarray(grasp.approach, dtype=np.float64).reshape(3)
        closing = np.asarray(grasp.closing, dtype=np.float64).reshape(3)
        half = float(grasp.width) / 2.0 * closing
        palm = position - finger * approach
        glyphs.append(
            np.stack(
                [
                    position - half,
                    palm - half,
                    palm + half,
                    position + half,
                    np.full(3, np.nan),
                    palm,
                    palm - finger * approach,
                ]
            )
        )
    return glyphs


def _hidden_edges(box: Box, towards: FloatArray) -> list[bool]:
    """Tell, per edge of :data:`EDGES`, whether both faces meeting there face away from us."""
    facing = box.rotation.T @ towards  # > 0: the + face of that axis faces the viewer
    hidden = []
    for i, j in EDGES:
        axis = int(np.flatnonzero(_CORNER_SIGNS[i] != _CORNER_SIGNS[j])[0])
        hidden.append(all(_CORNER_SIGNS[i][k] * facing[k] < 1e-9 for k in range(3) if k != axis))
    return hidden


# Drawing ----------------------------------------------------------------------------------------


def _plural(count: int, noun: str) -> str:
    return (
        f'{count} {noun}' if count == 1 else f'{count} {noun}{"es" if noun.endswith("x") else "s"}'
    )


def _format_length(value: float, unit: str) -> str:
    if unit == 'm' and value < 1.0:
        return f'{value * 100.0:g} cm' if value >= 0.01 else f'{value * 1000.0:g} mm'
    return f'{value:g} {unit}'.rstrip()


def _nice_length(span: float) -> float:
    """Return a 1-2-5 length of about a fifth of `span`."""
    raw = span / 5.0
    exponent = math.floor(math.log10(raw))
    steps = [step * 10.0**exponent for step in (1.0, 2.0, 5.0, 10.0)]
    return next(step for step in steps if step >= raw * (1.0 - 1e-9))


def _box_label(index: int, box: Box, unit: str) -> str:
    sizes = sorted((float(v) for v in box.extents), reverse=True)
    if unit == 'm' and max(sizes) < 1.0:
        text = ' × '.join(f'{v * 100.0:.1f}' for v in sizes) + ' cm'
    else:
        text = ' × '.join(f'{v:.3g}' for v in sizes) + f' {unit}'.rstrip()
    return f'box {index + 1}: {text}'


def _draw_panel(
    subfig: SubFigure,
    panel: Panel,
    *,
    views: list[View],
    view_angles: list[tuple[float, float]],
    frame: str | ArrayLike,
    max_points: int,
    point_size: float | None,
    max_grasps: int,
    unit: str,
    layout: tuple[float, float],
) -> None:
    """Draw one row; `layout` is (right edge of the views, top of the views) in row fractions."""
    right, top = layout
    all_points = _finite_points(panel.points)
    points = _subsample(all_points, max_points)
    boxes = list(panel.boxes)
    grasps = list(panel.grasps or [])[: max(max_grasps, 0)]
    rotation = _frame_rotation(frame, points, boxes)
    solid = np.concatenate([points, _box_corners(boxes)])
    origin = solid.mean(axis=0) if len(solid) else np.zeros(3)
    span = float(np.ptp(solid, axis=0).max()) if len(solid) else 0.0
    span = span if span > 0.0 else 1.0
    glyphs = _gripper_glyphs(grasps, finger=0.1 * span)
    # Per view: data coordinates -> (screen right, screen up, towards the viewer).
    projections = [_view_rotation(*angles) @ rotation.T for angles in view_angles]

    def project(xyz: FloatArray, k: int) -> FloatArray:
        return (xyz - origin) @ projections[k].T

    bounds = []
    for k in range(len(views)):
        flat = np.concatenate([project(solid, k)] + [project(g, k) for g in glyphs])[:, :2]
        flat = flat[np.all(np.isfinite(flat), axis=1)]
        bounds.append((flat.min(axis=0), flat.max(axis=0)) if len(flat) else (np.zeros(2),) * 2)
    half = 0.6 * max(float(np.max(high - low)) for low, high in bounds)
    half = half if half > 0.0 else 0.5 * span
    size = point_size
    if size is None:
        size = float(np.clip(4000.0 / max(len(points), 1), 0.5, 6.0))

    axes = subfig.subplots(
        1,
        len(views),
        squeeze=False,
        gridspec_kw={'left': 0.01, 'right': right, 'top': top, 'bottom': 0.01, 'wspace': 0.03},
    )[0]
    for k, ax in enumerate(axes):
        middle = (bounds[k][0] + bounds[k][1]) / 2.0
        ax.set_xlim(middle[0] - half, middle[0] + half)
        ax.set_ylim(middle[1] - 1.1 * half, middle[1] + 0.9 * half)  # room for the scale bar
        ax.set_aspect('equal', adjustable='box')
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_color('#c8c8c8')
        view = views[k]
        name = view if isinstance(view, str) else f'el {view[0]:g}°, az {view[1]:g}°'
        ax.text(
            0.03,
            0.97,
            name,
            transform=ax.transAxes,
            ha='left',
            va='top',
            fontsize=8,
            color='#555555',
        )
        if len(points):
            _draw_points(ax, project(points, k), size)
        towards = projections[k][2]  # the viewing direction, in data coordinates
        corners = [project(box.corners(), k) for box in boxes]
        _draw_boxes(ax, corners, [_hidden_edges(box, towards) for box in boxes])
        for g in reversed(range(len(glyphs))):
            xy = project(glyphs[g], k)
            best = g == 0
            ax.plot(
                xy[:, 0],
                xy[:, 1],
                color=BEST_GRASP_COLOR if best else GRASP_COLOR,
                lw=2.0 if best else 1.0,
                zorder=5 if best else 4,
                solid_capstyle='round',
            )
        _scale_bar(ax, half, unit)

    _legend(subfig, boxes, len(grasps), unit, anchor=(right + 0.005, top / 2.0))
    header = 1.0 - (1.0 - top) / 2.0
    title = subfig.text(
        0.01, header, panel.title or ' ', ha='left', va='center', fontsize=11, fontweight='bold'
    )
    counts = f'{_plural(len(all_points), "point")}, {_plural(len(boxes), "box")}'
    if len(points) < len(all_points):
        counts += f' ({len(points)} drawn)'
    # The counts follow the title on its baseline, whatever the title's length.
    annotation = Annotation(
        counts,
        xy=(1.0, 0.0),
        xycoords=title,
        xytext=(10, 0),
        textcoords='offset points',
        ha='left',
        va='bottom',
        fontsize=8,
        color='#666666',
    )
    subfig.add_artist(annotation)


def _legend(
    subfig: SubFigure, boxes: list[Box], n_grasps: int, unit: str, anchor: tuple[float, float]
) -> None:
    """Add a row's legend: box colours with sizes (names only when many), then the grasps."""
    many = len(boxes) > _LEGEND_ROWS
    shown = boxes[: 2 * _LEGEND_ROWS - 1] if len(boxes) > 2 * _LEGEND_ROWS else boxes
    handles = [
        Line2D(
            [],
            [],
            color=BOX_COLORS[b % len(BOX_COLORS)],
            lw=2.0,
            label=f'box {b + 1}' if many else _box_label(b, box, unit),
        )
        for b, box in enumerate(shown)
    ]
    if len(shown) < len(boxes):
        handles.append(Line2D([], [], color='none', label=f'+{len(boxes) - len(shown)} more'))
    if n_grasps:
        handles.append(Line2D([], [], color=BEST_GRASP_COLOR, lw=2.0, label='best grasp'))
        if n_grasps > 1:
            label = f'next {n_grasps - 1} grasps'
            handles.append(Line2D([], [], color=GRASP_COLOR, lw=1.0, label=label))
    if handles:
        subfig.legend(
            handles=handles,
            loc='center left',
            bbox_to_anchor=anchor,
            fontsize=8,
            frameon=False,
            handlelength=1.6,
            ncols=2 if many else 1,
            columnspacing=1.0,
        )


def _draw_points(ax: Axes, xyz: FloatArray, size: float) -> None:
    order = np.argsort(xyz[:, 2])  # far first, so near points are on top
    depth = xyz[order, 2]
    shade = (depth - depth.min()) / max(float(np.ptp(depth)), 1e-12)
    grey = 0.72 - 0.55 * shade
    ax.scatter(
        xyz[order, 0],
        xyz[order, 1],
        s=size,
        c=np.repeat(grey[:, None], 3, axis=1),
        linewidths=0,
        rasterized=True,
        zorder=1,
    )


def _draw_boxes(ax: Axes, corners: list[FloatArray], hidden: list[list[bool]]) -> None:
    """Draw box wireframes: front edges solid, edges hidden behind their own box dashed."""
    for behind in (True, False):
        segments, colors = [], []
        for index, (box_corners, box_hidden) in enumerate(zip(corners, hidden, strict=True)):
            for (i, j), is_hidden in zip(EDGES, box_hidden, strict=True):
                if is_hidden == behind:
                    segments.append(box_corners[[i, j], :2])
                    colors.append(BOX_COLORS[index % len(BOX_COLORS)])
        if not segments:
            continue
        style: dict[str, Any] = {
            'linewidths': 0.9,
            'linestyles': (0, (3, 2)),
            'alpha': 0.75,
            'zorder': 2,
        }
        if not behind:
            style = {'linewidths': 1.8, 'linestyles': 'solid', 'alpha': 1.0, 'zorder': 3}
        ax.add_collection(LineCollection(segments, colors=colors, capstyle='round', **style))


def _scale_bar(ax: Axes, half: float, unit: str) -> None:
    length = _nice_length(2.0 * half)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    x, y = x0 + 0.05 * (x1 - x0), y0 + 0.04 * (y1 - y0)
    ax.plot([x, x + length], [y, y], color='#333333', lw=2.0, solid_capstyle='butt', zorder=6)
    ax.text(
        x + length / 2.0,
        y + 0.015 * (y1 - y0),
        _format_length(length, unit),
        ha='center',
        va='bottom',
        fontsize=7,
        color='#333333',
        zorder=6,
    )
