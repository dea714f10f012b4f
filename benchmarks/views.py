"""
Single views against whole objects: boxes, plates and grasps (issues 15 and 16), one command.

    .venv/bin/python benchmarks/views.py                    # 6 views per mesh, every config
    .venv/bin/python benchmarks/views.py --quick            # 2 views per mesh
    .venv/bin/python benchmarks/views.py --config node --no-grasps --no-scans
    .venv/bin/python benchmarks/views.py --json out/views.json --pictures out/views

What runs: every shared mesh (:data:`mvbb_ros.evaluation.views.TABLE_MODELS`) stands on a table
and is seen by the virtual depth camera from random viewpoints (30-70 degrees above the table,
0.5-1.0 m away, Kinect-like noise, only the object's pixels:
:func:`mvbb_ros.evaluation.views.single_views`); each view's cloud (float32, metres, camera
optical frame) goes through the node's pipeline
(:func:`mvbb_ros.pipeline.process.process_points`) for each configuration, at t = 0.90, 0.94 and
0.98, and the leaf boxes are measured against the whole mesh
(:mod:`mvbb_ros.evaluation.coverage`): coverage of the whole surface (boxes grown by 2 mm),
total box volume over the convex hull's, share of boxes under 1 cm, boxes per view. The same
plate share and box counts are measured on every real scan of the shared ``scans`` folder
(:func:`mvbb_ros.evaluation.views.real_scans`).

Grasps (at t = 0.94, the node's default) are judged on the whole mesh on the table
(:mod:`mvbb_ros.evaluation.grasp_judge`: 2 x 2 cm pads, opening = the configuration's
``gripper_max_width``, mu 0.5, finger depths 0.5-3 cm): does the top-ranked grasp hold, does one
of the top five, what share of all hypotheses holds; the top grasp's Ferrari-Canny epsilon with
the project's Figure 6 simulator; steadiness: the same view with fresh sensor noise, 4 frames,
the share of consecutive frame pairs whose top grasps are the same (1 cm, 15 degrees, a half
turn about the approach allowed); and the pipeline's cost per cloud (median ms over the frames).

Configurations are data (:data:`CONFIGS`, or a JSON file given with ``--configs``): a label
mapped to ``{"preset": "node" | "paper", "params": {name: value}, "up": bool}``, where
``params`` are node parameters (``PipelineSettings.updated``) and ``up`` passes the view's up
direction (the world's +z in the camera frame, what a robot with TF knows) as
``up_direction``. ``gain_threshold`` is set by the benchmark. A configuration whose parameters
the pipeline does not have (yet) is skipped with a one-line message.

Means are over views (coverage, volume ratio, boxes per view) or pooled over boxes (the thin
share); the top-1 and top-5 shares count a view without grasps as a failure; the hypotheses'
share is the mean over views that have hypotheses; steadiness is pooled over frame pairs.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
import json
from pathlib import Path
import statistics
import subprocess
import sys
import time
from typing import Any

from mvbb_ros.evaluation.shared_data import shared_data_folder

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()

#: The paper's thresholds; grasps are judged at the node's default.
THRESHOLDS: tuple[float, ...] = (0.90, 0.94, 0.98)
GRASP_THRESHOLD = 0.94
#: Frames of one static view for steadiness (fresh sensor noise each).
STEADY_FRAMES = 4
#: Top grasps that count for "one of the top five".
TOP_K = 5
#: Meshes whose first view is drawn with --pictures.
PICTURE_MESHES = ('mug', 'cereal', 'bunny', 'duck')

#: The configurations: label -> preset, node parameter overrides and whether the view's up
#: direction is passed (robot with TF) or not (unknown). New approaches are new entries.
#: The node's defaults before issue 15: the paper's boxes on filtered points, one object.
_BEFORE = {
    'shape_completion': 'none',
    'min_box_thickness': 0.0,
    'cluster_tolerance': 0.0,
    'rescore_cuts': 0,
}
CONFIGS: dict[str, dict[str, Any]] = {
    'paper': {'preset': 'paper', 'params': {}, 'up': False},
    'before': {'preset': 'node', 'params': _BEFORE, 'up': False},
    # Issue 15's approaches (docs/single_views.md): a thickness floor alone, extrusion, mirror.
    'floor': {'preset': 'node', 'params': {'shape_completion': 'none'}, 'up': False},
    'extrude+up': {'preset': 'node', 'params': {'shape_completion': 'extrude'}, 'up': True},
    'mirror, no floor+up': {'preset': 'node', 'params': {'min_box_thickness': 0.0}, 'up': True},
    # The node's defaults (mirror completion, 1 cm floor, objects separated), with and without
    # the up direction a robot knows from TF.
    'node': {'preset': 'node', 'params': {}, 'up': False},
    'node+up': {'preset': 'node', 'params': {}, 'up': True},
    # The node's defaults with the paper's single best cut by theta instead of the best of
    # three cuts by their fitted parts (the default until 2026-12-02, docs/single_views.md).
    'theta cut': {'preset': 'node', 'params': {'rescore_cuts': 0}, 'up': False},
    'theta cut+up': {'preset': 'node', 'params': {'rescore_cuts': 0}, 'up': True},
    # Issue 16's measuring conditions: a 14 cm opening, up from the table; the node's grasps
    # (refined on the points) and the paper's hypotheses on the same boxes (refinement off).
    'node+up/14cm': {'preset': 'node', 'params': {'gripper_max_width': 0.14}, 'up': True},
    'seeds+up/14cm': {
        'preset': 'node',
        'params': {'gripper_max_width': 0.14, 'grasp_refinement': False},
        'up': True,
    },
}

#: Columns of the raw rows (``--json``), one row per view (or scan), configuration and t.
VIEW_COLUMNS = (
    'config',
    'threshold',
    'mesh',
    'view',
    'points',
    'boxes',
    'thin',
    'coverage',
    'volume_ratio',
    'ms',
)
SCAN_COLUMNS = ('config', 'threshold', 'scan', 'points', 'boxes', 'thin', 'ms')
GRASP_COLUMNS = (
    'config',
    'mesh',
    'view',
    'hypotheses',
    'top1',
    'top5',
    'holding',
    'status',
    'epsilon',
    'same_pairs',
    'pairs',
    'kept',
    'ms',
    'refine_ms',
    'width',
    'contact_width',
    'thin_widths',
    'below',
    'far_side',
    'grasps_checked',
)
#: An approach rises more than this above the horizontal: from below (the grasp stage's
#: ``max_approach_elevation_deg`` default).
BELOW_SIN = 0.7071067811865476
#: Published widths under this on an object thicker than :data:`THICK_OBJECT` are too thin.
THIN_WIDTH = 0.01
THICK_OBJECT = 0.03


@dataclass(frozen=True)
class Config:
    """One configuration: a preset, node parameter overrides, and whether up is passed."""

    label: str
    preset: str = 'node'
    params: Mapping[str, Any] = field(default_factory=dict)
    up: bool = False

    @classmethod
    def from_data(cls, label: str, data: Mapping[str, Any]) -> Config:
        """Build from a JSON-like mapping (keys preset, params, up)."""
        unknown = set(data) - {'preset', 'params', 'up'}
        if unknown:
            raise ValueError(f'config {label!r}: unknown keys {sorted(unknown)}')
        return cls(
            label,
            str(data.get('preset', 'node')),
            dict(data.get('params', {})),
            bool(data.get('up', False)),
        )

    def settings(self, threshold: float, up: Sequence[float] | None = None):
        """Return the PipelineSettings at threshold t (and up, when passed and known)."""
        from mvbb_ros.pipeline.settings import PRESETS

        if self.preset not in PRESETS:
            raise ValueError(f'unknown preset {self.preset!r}; known: {", ".join(PRESETS)}')
        changes = {**self.params, 'gain_threshold': threshold}
        if self.up and up is not None:
            changes['up_direction'] = [float(v) for v in up]
        return PRESETS[self.preset].updated(changes)

    def unusable(self) -> str | None:
        """Return why the pipeline cannot run this configuration today, or None."""
        try:
            self.settings(GRASP_THRESHOLD, (0.0, 0.0, 1.0))
        except ValueError as error:
            return str(error)
        return None


def usable_configs(configs: Iterable[Config], log=print) -> list[Config]:
    """Keep the configurations the pipeline can run; say in one line why others are skipped."""
    kept = []
    for config in configs:
        reason = config.unusable()
        if reason is None:
            kept.append(config)
        else:
            log(f'skipping config {config.label!r}: {reason.splitlines()[0][:160]}')
    return kept


# Measuring -------------------------------------------------------------------------------------


def measure_view(view, config: Config, thresholds: Sequence[float], grasps: bool):
    """
    Run a configuration on one view; return (box rows, grasp row or None).

    Box rows: one per threshold (frame 0). Grasp row (t = 0.94, when `grasps`): the judge on
    frame 0's hypotheses, the simulator's epsilon of the top one, and the top grasps of
    :data:`STEADY_FRAMES` frames of the same view with fresh noise, each frame given the
    previous frame's top grasp (the node's hysteresis); the top grasp's published width and
    the judge's contact distance; how many published grasps are thinner than 1 cm (on objects
    thicker than 3 cm), approach from below or from the far side.
    """
    from mvbb_ros.evaluation.grasp_judge import STATUS_NAMES, steady_pairs
    from mvbb_ros.pipeline.process import process_points

    rows, results = [], {}
    for threshold in sorted({*thresholds, *([GRASP_THRESHOLD] if grasps else [])}):
        result = process_points(view.points, config.settings(threshold, view.up))
        results[threshold] = result
        if threshold not in thresholds:
            continue
        metrics = view.box_metrics(result.leaves)
        rows.append(
            {
                'config': config.label,
                'threshold': threshold,
                'mesh': view.obj.name,
                'view': view.index,
                'points': len(view.points),
                'boxes': metrics.boxes,
                'thin': metrics.thin,
                'coverage': metrics.coverage,
                'volume_ratio': metrics.volume_ratio,
                'ms': result.total_ms,
            }
        )
    if not grasps:
        return rows, None
    settings = config.settings(GRASP_THRESHOLD, view.up)
    first = results[GRASP_THRESHOLD]
    width = settings.grasps.gripper_max_width
    hypotheses = first.grasps
    verdicts = view.judge_grasps(hypotheses, width)
    holds = verdicts.holds
    epsilon = float(view.simulated_epsilon(hypotheses[:1], width)[0]) if hypotheses else 0.0
    tops = [hypotheses[0] if hypotheses else None]
    costs = [first.total_ms]
    refine_costs = [first.timings_ms.get('refine', 0.0)]
    kept = 0
    for number in range(1, STEADY_FRAMES):
        result = process_points(view.frame(number), settings, previous=tops[-1])
        tops.append(result.grasps[0] if result.grasps else None)
        costs.append(result.total_ms)
        refine_costs.append(result.timings_ms.get('refine', 0.0))
        kept += bool(result.refinement is not None and result.refinement.kept_previous)
    same, pairs = steady_pairs(tops)
    feasibility = published_checks(view, hypotheses)
    grasp_row = {
        'config': config.label,
        'mesh': view.obj.name,
        'view': view.index,
        'hypotheses': len(hypotheses),
        'top1': bool(len(holds) and holds[0]),
        'top5': bool(holds[:TOP_K].any()),
        'holding': float(holds.mean()) if len(holds) else None,
        'status': STATUS_NAMES[int(verdicts.status[0])] if len(holds) else 'none',
        'epsilon': epsilon,
        'same_pairs': same,
        'pairs': pairs,
        'kept': kept,
        'ms': statistics.median(costs),
        'refine_ms': statistics.median(refine_costs),
        'width': float(hypotheses[0].width) if hypotheses else None,
        'contact_width': _contact_width(verdicts),
        **feasibility,
        'grasps_checked': None if first.refinement is None else first.refinement.candidates,
    }
    return rows, grasp_row


def _contact_width(verdicts) -> float | None:
    """Return the judge's distance between the top grasp's two contacts (None without)."""
    import numpy as np

    if not len(verdicts) or not np.all(np.isfinite(verdicts.contacts[0])):
        return None
    return float(np.linalg.norm(verdicts.contacts[0, 0] - verdicts.contacts[0, 1]))


def published_checks(view, grasps) -> dict[str, int]:
    """
    Count the published grasps that are too thin, from below or from the far side.

    Thin: width under :data:`THIN_WIDTH` on an object whose smallest extent exceeds
    :data:`THICK_OBJECT`. Below: the approach rises more than 45 degrees (world up). Far side:
    the approach points back towards the camera (its dot product with the direction from the
    camera to the object's centre is negative).
    """
    import numpy as np

    if not grasps:
        return {'thin_widths': 0, 'below': 0, 'far_side': 0}
    approach = np.array([np.asarray(g.approach, dtype=np.float64) for g in grasps])
    widths = np.array([g.width for g in grasps])
    thick = float(np.min(np.ptp(view.obj.vertices, axis=0))) > THICK_OBJECT
    sight = view.to_camera(view.obj.center)
    sight = sight / np.linalg.norm(sight)
    return {
        'thin_widths': int(np.count_nonzero(widths < THIN_WIDTH)) if thick else 0,
        'below': int(np.count_nonzero(approach @ view.up > BELOW_SIN)),
        'far_side': int(np.count_nonzero(approach @ sight < -1e-6)),
    }


def measure_scan(scan, config: Config, thresholds: Sequence[float]) -> list[dict[str, Any]]:
    """Run a configuration on one real scan at each threshold; one row each."""
    from mvbb_ros.evaluation.coverage import thin_count
    from mvbb_ros.pipeline.process import process_points

    rows = []
    for threshold in thresholds:
        result = process_points(scan.points, config.settings(threshold, scan.up))
        rows.append(
            {
                'config': config.label,
                'threshold': threshold,
                'scan': scan.name,
                'points': len(scan.points),
                'boxes': len(result.leaves),
                'thin': thin_count(result.leaves),
                'ms': result.total_ms,
            }
        )
    return rows


# Tables ------------------------------------------------------------------------------------------


def _mean(values: Iterable[float]) -> float:
    items = [v for v in values if v is not None]
    return sum(items) / len(items) if items else float('nan')


def _share(part: float, whole: float) -> float:
    return part / whole if whole else float('nan')


def _pct(value: float) -> str:
    return '-' if value != value else f'{100.0 * value:.0f} %'


def _table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


VIEW_TABLE_HEADER = (
    'config',
    't',
    'views',
    'coverage',
    'volume / hull',
    'boxes < 1 cm',
    'boxes / view',
    'ms (median)',
)


def _by_threshold(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]):
    """Yield (label, threshold, rows of that configuration and threshold)."""
    for label in labels:
        for threshold in sorted({r['threshold'] for r in rows if r['config'] == label}):
            yield (
                label,
                threshold,
                [r for r in rows if r['config'] == label and r['threshold'] == threshold],
            )


def _thin_share(rows: Sequence[Mapping[str, Any]]) -> str:
    """Return the share of thin boxes, pooled over the rows' boxes."""
    return _pct(_share(sum(r['thin'] for r in rows), sum(r['boxes'] for r in rows)))


def view_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """Means over views per configuration and threshold."""
    out = [
        (
            label,
            f'{threshold:.2f}',
            str(len(sel)),
            _pct(_mean(r['coverage'] for r in sel)),
            f'{_mean(r["volume_ratio"] for r in sel):.2f}',
            _thin_share(sel),
            f'{_mean(r["boxes"] for r in sel):.1f}',
            f'{statistics.median(r["ms"] for r in sel):.0f}',
        )
        for label, threshold, sel in _by_threshold(rows, labels)
    ]
    return _table(VIEW_TABLE_HEADER, out)


def mesh_table(
    rows: Sequence[Mapping[str, Any]], labels: Sequence[str], threshold: float = GRASP_THRESHOLD
) -> str:
    """Per mesh at one threshold: coverage, volume ratio, thin share and boxes per config."""
    header = ['mesh']
    for label in labels:
        header += [f'{label} cov', f'{label} vol', f'{label} thin', f'{label} boxes']
    meshes = list(dict.fromkeys(r['mesh'] for r in rows))
    out = []
    for mesh in meshes:
        cells = [mesh]
        for label in labels:
            sel = [
                r
                for r in rows
                if r['config'] == label and r['mesh'] == mesh and r['threshold'] == threshold
            ]
            cells += [
                _pct(_mean(r['coverage'] for r in sel)),
                f'{_mean(r["volume_ratio"] for r in sel):.2f}',
                _thin_share(sel),
                f'{_mean(r["boxes"] for r in sel):.1f}',
            ]
        out.append(cells)
    return _table(header, out)


SCAN_TABLE_HEADER = ('config', 't', 'scans', 'boxes / scan', 'boxes < 1 cm', 'ms (median)')


def scan_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """Real scans per configuration and threshold: boxes per scan and the thin share."""
    out = [
        (
            label,
            f'{threshold:.2f}',
            str(len(sel)),
            f'{_mean(r["boxes"] for r in sel):.1f}',
            _thin_share(sel),
            f'{statistics.median(r["ms"] for r in sel):.0f}',
        )
        for label, threshold, sel in _by_threshold(rows, labels)
    ]
    return _table(SCAN_TABLE_HEADER, out)


GRASP_TABLE_HEADER = (
    'config',
    'views',
    'top-1 holds',
    'any of top 5',
    'hypotheses holding',
    'steady pairs',
    'top epsilon (mean)',
    'top force-closure',
    'hypotheses / view',
    'ms (median)',
)


def grasp_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """Grasps at t = 0.94 per configuration."""
    out = []
    for label in labels:
        sel = [r for r in rows if r['config'] == label]
        if not sel:
            continue
        out.append(
            (
                label,
                str(len(sel)),
                _pct(_mean(float(r['top1']) for r in sel)),
                _pct(_mean(float(r['top5']) for r in sel)),
                _pct(_mean(r['holding'] for r in sel)),
                _pct(_share(sum(r['same_pairs'] for r in sel), sum(r['pairs'] for r in sel))),
                f'{_mean(r["epsilon"] for r in sel):.4f}',
                _pct(_mean(float(r['epsilon'] > 0.0) for r in sel)),
                f'{_mean(r["hypotheses"] for r in sel):.1f}',
                f'{statistics.median(r["ms"] for r in sel):.0f}',
            )
        )
    return _table(GRASP_TABLE_HEADER, out)


FEASIBILITY_HEADER = (
    'config',
    'views',
    'grasps',
    'widths < 1 cm',
    'from below',
    'far side',
    'top width - contacts (median)',
    'kept by hysteresis',
    'lines checked / view',
    'refine ms (median)',
)


def feasibility_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """
    Count published grasps per configuration: too thin, from below, from the far side.

    The width column is the median over views of the top grasp's published width minus the
    judge's distance between its contacts (the width margin plus what the points missed).
    """
    out = []
    for label in labels:
        sel = [r for r in rows if r['config'] == label]
        if not sel:
            continue
        gaps = [
            r['width'] - r['contact_width']
            for r in sel
            if r.get('width') is not None and r.get('contact_width') is not None
        ]
        checked = [r['grasps_checked'] for r in sel if r.get('grasps_checked') is not None]
        out.append(
            (
                label,
                str(len(sel)),
                str(sum(r['hypotheses'] for r in sel)),
                str(sum(r.get('thin_widths', 0) for r in sel)),
                str(sum(r.get('below', 0) for r in sel)),
                str(sum(r.get('far_side', 0) for r in sel)),
                f'{100 * statistics.median(gaps):+.1f} cm' if gaps else '-',
                f'{sum(r.get("kept", 0) for r in sel)}/{sum(r["pairs"] for r in sel)}',
                f'{_mean(checked):.0f}' if checked else '-',
                f'{statistics.median(r.get("refine_ms", 0.0) for r in sel):.0f}',
            )
        )
    return _table(FEASIBILITY_HEADER, out)


def mesh_grasp_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """Per mesh: views whose top grasp holds and views where one of the top five does."""
    header = ['mesh']
    for label in labels:
        header += [f'{label} top-1', f'{label} top-5']
    out = []
    for mesh in dict.fromkeys(r['mesh'] for r in rows):
        cells = [mesh]
        for label in labels:
            sel = [r for r in rows if r['config'] == label and r['mesh'] == mesh]
            cells += [
                f'{sum(r["top1"] for r in sel)}/{len(sel)}',
                f'{sum(r["top5"] for r in sel)}/{len(sel)}',
            ]
        out.append(cells)
    return _table(header, out)


def status_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> str:
    """How the top grasp ended, per configuration (the judge's furthest step)."""
    from mvbb_ros.evaluation.grasp_judge import STATUS_NAMES

    names = (*STATUS_NAMES, 'none')
    out = []
    for label in labels:
        sel = [r['status'] for r in rows if r['config'] == label]
        if sel:
            out.append((label, *(str(sel.count(name)) for name in names)))
    return _table(('config', *names), out)


# Pictures ----------------------------------------------------------------------------------------


def draw_view(path: Path, view, results: Sequence[tuple[str, Any, Any]]) -> Path:
    """
    Draw one view: per configuration the cloud and the whole mesh, with its boxes and best grasp.

    Views: the camera's own, from the top (world z) and from the side (perpendicular to the
    camera's azimuth), all in world-aligned axes.
    """
    from mvbb_ros.cli.render import Panel, render_panels
    import numpy as np

    surface = view.surface_in_camera()[:: max(1, len(view.obj.surface) // 4000)]
    panels = []
    for label, result, verdicts in results:
        best = result.grasps[:1]
        verdict = 'no grasp'
        if best:
            verdict = 'best grasp holds' if verdicts.holds[0] else 'best grasp fails'
        head = f'{label}: {len(result.leaves)} boxes, {verdict}'
        panels.append(Panel(view.points, result.leaves, grasps=best, title=f'{head} (cloud)'))
        panels.append(Panel(surface, result.leaves, grasps=best, title=f'{head} (whole mesh)'))
    elevation, azimuth = round(view.elevation_deg), round(view.azimuth_deg) % 360
    views = [(elevation, azimuth), 'top', (0, (azimuth + 90) % 360)]
    title = (
        f'{view.name}: {len(view.points)} points, camera {view.distance:.2f} m, '
        f'{view.elevation_deg:.0f} deg up; views: camera, top, side'
    )
    frame = np.asarray(view.camera_pose[:3, :3]).T  # world axes in camera coordinates
    return render_panels(path, panels, views=views, frame=frame, title=title, max_grasps=1)


# Running -----------------------------------------------------------------------------------------


@dataclass
class Results:
    """Everything one run measured (raw rows, for tables and --json)."""

    configs: list[str]
    skipped: dict[str, str]
    views: list[dict[str, Any]] = field(default_factory=list)
    grasps: list[dict[str, Any]] = field(default_factory=list)
    scans: list[dict[str, Any]] = field(default_factory=list)

    def tables(self) -> str:
        """Return every table as markdown."""
        parts = []
        if self.views:
            parts += ['## Single views: means over views\n', view_table(self.views, self.configs)]
            parts += [
                f'\n## Per mesh at t = {GRASP_THRESHOLD:.2f}\n',
                mesh_table(self.views, self.configs),
            ]
        if self.scans:
            parts += ['\n## Real scans\n', scan_table(self.scans, self.configs)]
        if self.grasps:
            parts += [
                f'\n## Grasps on the whole mesh (t = {GRASP_THRESHOLD:.2f})\n',
                grasp_table(self.grasps, self.configs),
                '\nPer mesh: views whose top grasp holds, and where one of the top 5 does:\n',
                mesh_grasp_table(self.grasps, self.configs),
                "\nHow the top grasp ends (the judge's furthest step):\n",
                status_table(self.grasps, self.configs),
                "\nPublished grasps: widths, feasibility, hysteresis and the refinement's cost:\n",
                feasibility_table(self.grasps, self.configs),
            ]
        return '\n'.join(parts)


def run(
    views: Iterable[Any],
    configs: Sequence[Config],
    *,
    thresholds: Sequence[float] = THRESHOLDS,
    grasps: bool = True,
    scans: Sequence[Any] = (),
    pictures: Path | None = None,
    log=print,
) -> Results:
    """Measure every usable configuration on the views and scans; return the raw rows."""
    usable = usable_configs(configs, log)
    results = Results(
        configs=[c.label for c in usable],
        skipped={c.label: str(c.unusable()) for c in configs if c not in usable},
    )
    drawn: set[str] = set()
    for view in views:
        start = time.perf_counter()
        drawing = []
        for config in usable:
            rows, grasp_row = measure_view(view, config, thresholds, grasps)
            results.views += rows
            if grasp_row is not None:
                results.grasps.append(grasp_row)
            if pictures is not None and view.obj.name in PICTURE_MESHES:
                drawing.append(config)
        if drawing and view.obj.name not in drawn:
            drawn.add(view.obj.name)
            path = draw_picture(pictures, view, drawing)
            log(f'  drew {path}')
        log(
            f'  {view.name}: {len(view.points)} points, {time.perf_counter() - start:.1f} s',
        )
    for scan in scans:
        for config in usable:
            results.scans += measure_scan(scan, config, thresholds)
        log(f'  scan {scan.name}: {len(scan.points)} points')
    return results


def draw_picture(folder: Path, view, configs: Sequence[Config]) -> Path:
    """Run each configuration at t = 0.94 on the view again and draw it (see draw_view)."""
    from mvbb_ros.pipeline.process import process_points

    results = []
    for config in configs:
        settings = config.settings(GRASP_THRESHOLD, view.up)
        result = process_points(view.points, settings)
        verdicts = view.judge_grasps(result.grasps[:1], settings.grasps.gripper_max_width)
        results.append((config.label, result, verdicts))
    folder.mkdir(parents=True, exist_ok=True)
    return draw_view(folder / f'{view.obj.name}_{view.index}.png', view, results)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    parser.add_argument('--views', type=int, default=6, help='views per mesh (default 6)')
    parser.add_argument('--quick', action='store_true', help='2 views per mesh')
    parser.add_argument(
        '--config',
        action='append',
        metavar='LABEL',
        help='run only this configuration (repeatable); default: all',
    )
    parser.add_argument(
        '--configs',
        type=Path,
        metavar='JSON',
        help='a JSON file {label: {"preset", "params", "up"}} added to (or replacing) CONFIGS',
    )
    parser.add_argument(
        '--meshes', nargs='+', metavar='NAME', help='only these meshes (default: all)'
    )
    parser.add_argument('--seed', type=int, default=0, help='viewpoint and noise seed')
    parser.add_argument('--no-grasps', action='store_true', help='skip the grasp table')
    parser.add_argument(
        '--scans',
        action=argparse.BooleanOptionalAction,
        default=True,
        help='measure the real scans too (default: yes)',
    )
    parser.add_argument('--json', type=Path, metavar='OUT', help='write the raw rows here')
    parser.add_argument('--pictures', type=Path, metavar='DIR', help='draw a few views here')
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    from mvbb_ros.evaluation.views import MODEL_BY_NAME, real_scans, TABLE_MODELS, views_of

    data = dict(CONFIGS)
    if args.configs is not None:
        data.update(json.loads(args.configs.read_text()))
    configs = [Config.from_data(label, value) for label, value in data.items()]
    if args.config:
        missing = sorted(set(args.config) - set(data))
        if missing:
            print(f'unknown config {missing}; known: {", ".join(data)}', file=sys.stderr)
            return 2
        configs = [c for c in configs if c.label in args.config]
    models_dir = args.data / 'models'
    if not models_dir.is_dir():
        print(f'shared data not found: {models_dir} (set MVBB_SHARED_DATA)', file=sys.stderr)
        return 1
    models = TABLE_MODELS
    if args.meshes:
        unknown = sorted(set(args.meshes) - set(MODEL_BY_NAME))
        if unknown:
            print(f'unknown mesh {unknown}; known: {", ".join(MODEL_BY_NAME)}', file=sys.stderr)
            return 2
        models = tuple(MODEL_BY_NAME[name] for name in args.meshes)
    count = 2 if args.quick else args.views
    commit = subprocess.run(
        ['git', 'log', '-1', '--format=%h %s'], capture_output=True, text=True, cwd=REPO
    ).stdout.strip()
    print(f'commit: {commit}')
    print(
        f'{len(models)} meshes x {count} views, seed {args.seed}; thresholds '
        f'{", ".join(f"{t:.2f}" for t in THRESHOLDS)}; grasps at t = {GRASP_THRESHOLD:.2f}'
        + ('' if args.no_grasps else f', steadiness over {STEADY_FRAMES} frames')
    )
    for config in configs:
        print(
            f'config {config.label}: preset {config.preset}, params {dict(config.params)}, '
            f'up {"passed" if config.up else "not passed"}'
        )
    start = time.perf_counter()
    scans = real_scans(args.data / 'scans') if args.scans else []

    def log(message: str) -> None:
        print(message, file=sys.stderr if message.startswith('  ') else sys.stdout, flush=True)

    results = run(
        views_of(models_dir, models, count, seed=args.seed),
        configs,
        grasps=not args.no_grasps,
        scans=scans,
        pictures=args.pictures,
        log=log,
    )
    print()
    print(results.tables())
    print(f'\n{time.perf_counter() - start:.0f} s')
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        raw = {
            'commit': commit,
            'views_per_mesh': count,
            'seed': args.seed,
            'configs': {c.label: data[c.label] for c in configs},
            'skipped': results.skipped,
            'views': results.views,
            'grasps': results.grasps,
            'scans': results.scans,
        }
        args.json.write_text(json.dumps(raw, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
