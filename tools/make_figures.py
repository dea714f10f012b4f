"""
Regenerate the pictures under docs/ from the shared models and the project's own code.

    .venv/bin/python tools/make_figures.py [--shared ../shared/data] [--out docs]

- bunny_thresholds.png: the Stanford Bunny's vertices decomposed at t = 0.90, 0.94, 0.98;
- grasps_mug.png, grasps_bunny.png: the ranked grasp hypotheses on the mug (5,000 surface
  samples) and the bunny (vertices);
- grasp_convention.png: which gripper axis approaches and which closes;
- single_views_scans.png, single_views_virtual.png: four real scans and two virtual views of
  the shared meshes, the paper's algorithm beside the node's defaults (docs/single_views.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mvbb_ros.cli.render import Panel, render_panels
from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.evaluation.views import load_table_object, MODEL_BY_NAME, real_scans, single_views
from mvbb_ros.geometry.box import Box, EDGES
from mvbb_ros.geometry.decomposition.tree import decompose
from mvbb_ros.geometry.grasping.hypotheses import grasp_hypotheses
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
THRESHOLDS = (0.90, 0.94, 0.98)
#: The GraspIt! mug is in millimetres: gripper width and standoff scaled to it.
MUG_SCALE = 1000.0


def bunny_thresholds(models: Path, out: Path) -> None:
    """Draw the Bunny's decomposition at the paper's three thresholds, one row each."""
    points = np.load(models / 'bunny_vertices.npy').astype(np.float64)
    panels = []
    for threshold in THRESHOLDS:
        decomposition = decompose(points, gain_threshold=threshold)
        count = len(decomposition.leaves)
        panels.append(
            Panel(points, decomposition.leaves, title=f't = {threshold:.2f}: {count} boxes')
        )
    render_panels(out / 'bunny_thresholds.png', panels, title='Stanford Bunny (35,947 vertices)')


def grasps_on(points: np.ndarray, scale: float, name: str, out: Path, unit: str) -> None:
    """Draw the t = 0.94 boxes and best grasps; `scale` converts metres to the model's unit."""
    decomposition = decompose(points, gain_threshold=0.94)
    grasps = grasp_hypotheses(decomposition, gripper_max_width=0.08 * scale, standoff=0.05 * scale)
    title = f'{name}: t = 0.94, {len(decomposition.leaves)} boxes, {len(grasps)} grasps (best 8)'
    render_panels(
        out / f'grasps_{name.lower()}.png',
        [Panel(points, decomposition.leaves, grasps=grasps, title=title)],
        unit=unit,
    )


#: The real scans and virtual views of the single-view figures: a box, a bowl, a stereo mug and
#: a laser scan of the bunny; the cereal box and the duck.
FIGURE_SCANS = (
    'mosd_learn38_obj3',
    'mosd_learn33_obj3',
    'pcl_stereo_mug',
    'bunny_rangescan_bun000',
)
FIGURE_VIEWS = ('cereal', 'duck')


def _single_view_panels(
    name: str, points: np.ndarray, up: np.ndarray | None, surface: np.ndarray | None = None
) -> list[Panel]:
    """Return the paper's and the node's boxes of one view (and on the whole mesh, if given)."""
    panels = []
    for label, settings in (('paper', PipelineSettings.paper()), ('node', PipelineSettings())):
        if up is not None and label == 'node':
            settings = settings.updated({'up_direction': [float(v) for v in up]})
        result = process_points(points, settings)
        thin = sum(float(np.min(box.extents)) < 0.01 for box in result.leaves)
        title = f'{name}, {label}: {len(result.leaves)} boxes, {thin} under 1 cm'
        panels.append(Panel(points, result.leaves, grasps=result.grasps[:1], title=title))
        if surface is not None:
            whole = Panel(surface, result.leaves, title=f'{name}, {label}: on the whole mesh')
            panels.append(whole)
    return panels


def single_view_figures(shared: Path, out: Path) -> None:
    """Draw real scans and virtual views: the paper's boxes beside the node's defaults."""
    scans = {scan.name: scan for scan in real_scans(shared / 'scans')}
    scan_panels = []
    for name in FIGURE_SCANS:
        scan = scans[name]
        scan_panels += _single_view_panels(name, scan.points, scan.up)
    view_panels = []
    for name in FIGURE_VIEWS:
        view = next(
            iter(single_views(load_table_object(shared / 'models', MODEL_BY_NAME[name]), 1))
        )
        surface = view.surface_in_camera()[:: max(1, len(view.obj.surface) // 4000)]
        view_panels += _single_view_panels(name, view.points, view.up, surface)
    for name, panels, title in (
        (
            'single_views_scans',
            scan_panels,
            'Real single views: the paper beside the node (objects, hidden side, 1 cm floor)',
        ),
        (
            'single_views_virtual',
            view_panels,
            'Virtual views against the whole mesh (the node with the up direction)',
        ),
    ):
        render_panels(
            out / f'{name}.png',
            panels,
            views=('camera', 'front'),
            frame='data',
            max_grasps=1,
            max_points=5000,
            dpi=80,
            title=title,
        )


def _arrow(
    axes: object, origin: np.ndarray, direction: np.ndarray, color: str, label: str
) -> None:
    axes.quiver(*origin, *direction, color=color, linewidth=2.5, arrow_length_ratio=0.15)
    tip = origin + 1.3 * direction
    axes.text(*tip, label, color=color, fontsize=11, ha='left', fontweight='bold')


def grasp_convention(out: Path) -> None:
    """Draw a box, one grasp on its top face and the gripper axes for both conventions."""
    box = Box(center=[0.0, 0.0, 0.0], rotation=np.eye(3), extents=[0.06, 0.04, 0.1])
    grasps = grasp_hypotheses([box], gripper_max_width=0.08, standoff=0.05)
    top = next(g for g in grasps if g.face == 4 and g.roll_deg == 0)
    figure = Figure(figsize=(10.0, 5.0))
    FigureCanvasAgg(figure)
    for column, axis_name in enumerate(('z', 'x')):
        grasp = next(
            g
            for g in grasp_hypotheses([box], approach_axis=axis_name, standoff=0.05)
            if g.face == top.face and g.roll_deg == 0
        )
        axes = figure.add_subplot(1, 2, column + 1, projection='3d')
        corners = box.corners()
        for i, j in EDGES:
            axes.plot(*corners[[i, j]].T, color='0.35', linewidth=1.2)
        rotation = grasp.rotation
        length = 0.045
        names = ('x', 'y', 'z')
        colors = ('tab:red', 'tab:green', 'tab:blue')
        for k in range(3):
            role = ''
            if np.allclose(rotation[:, k], grasp.approach):
                role = ' = approach'
            elif np.allclose(rotation[:, k], grasp.closing):
                role = ' = closing'
            _arrow(axes, grasp.position, length * rotation[:, k], colors[k], f'{names[k]}{role}')
        face_center = box.face_centers()[grasp.face]
        for sign in (-1.0, 1.0):
            finger = face_center + sign * grasp.width / 2 * grasp.closing
            axes.plot(
                *np.stack([finger - 0.02 * grasp.approach, finger]).T, color='k', linewidth=4
            )
        axes.scatter(*grasp.position, color='k', s=20)
        axes.set_title(f"approach_axis='{axis_name}'" + (' (default)' if axis_name == 'z' else ''))
        axes.set_box_aspect((1, 1, 1))
        axes.set_xlim(-0.06, 0.06)
        axes.set_ylim(-0.06, 0.06)
        axes.set_zlim(-0.02, 0.1)
        axes.view_init(elev=18, azim=-70)
        axes.set_axis_off()
        axes.set_xticks([])
        axes.set_yticks([])
        axes.set_zticks([])
    figure.suptitle(
        'Grasp pose on the top face: position = face centre + standoff x normal, '
        'approach = -normal, fingers (black) close across the face',
        fontsize=9,
    )
    figure.tight_layout()
    with atomic_path(out / 'grasp_convention.png') as tmp:
        figure.savefig(tmp, format='png', dpi=110)


def main() -> int:
    """Write every figure; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--shared', type=Path, default=REPO_ROOT.parent / 'shared' / 'data')
    parser.add_argument('--out', type=Path, default=REPO_ROOT / 'docs')
    args = parser.parse_args()
    models = args.shared / 'models'
    if not models.is_dir():
        print(f'shared models not found in {models}', file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    grasp_convention(args.out)
    bunny_thresholds(models, args.out)
    bunny = np.load(models / 'bunny_vertices.npy').astype(np.float64)
    grasps_on(bunny, 1.0, 'Bunny', args.out, unit='m')
    # The mug's mesh vertices lie on rings with empty layers between them, which turns boxes
    # into slabs; its area-uniform surface sample shows the object as a sensor would.
    mug = np.load(models / 'graspit_mug_surface5k.npy').astype(np.float64)
    grasps_on(mug, MUG_SCALE, 'Mug', args.out, unit='mm')
    single_view_figures(args.shared, args.out)
    for name in (
        'grasp_convention',
        'bunny_thresholds',
        'grasps_bunny',
        'grasps_mug',
        'single_views_scans',
        'single_views_virtual',
    ):
        print(f'wrote {args.out / name}.png')
    return 0


if __name__ == '__main__':
    sys.exit(main())
