"""
Grasp quality benchmark: reproduce the paper's Figure 6 on every shared model (issue 10).

For each mesh in the shared data's ``models/`` folder, score with the same parallel-jaw gripper
and soft-finger contact model (:mod:`mvbb_ros.evaluation`):

* the spherical baseline (the paper's 22104 grasps at 10 degrees),
* the 24 grasps of the root box of the model's vertices,
* the face-grasp hypotheses after decomposition at t = 0.90, 0.94 and 0.98,
* the same hypotheses refined on the model's even 5k surface sample (issue 16; ``--no-refine``
  skips them): :func:`mvbb_ros.evaluation.experiment.refined_hypotheses`, at most 200 each,

then write one (epsilon, V) scatter plot per model (``docs/grasp_quality_<model>.png``) and the
tables into ``docs/grasp_quality.md``, between the markers ``<!-- BEGIN GENERATED -->`` and
``<!-- END GENERATED -->`` (the hand-written discussion around them is kept).

Units: the GraspIt! models are in millimetres, the bunny in metres, Homer and the duck are
unitless. Every length of the experiment (gripper, standoff, sphere) is a multiple of each
model's diameter and the qualities are unit-free, so the models are used as they are.

Run (how long it takes: ``docs/performance.md``)::

    .venv/bin/python benchmarks/grasp_quality.py
    .venv/bin/python benchmarks/grasp_quality.py --models mug --spherical-step 20  # quick look
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import platform
import sys
import time

from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.evaluation.experiment import (
    CLAIM_CANDIDATE_FRACTION,
    CLAIM_QUALITY_FRACTION,
    compare_grasp_sets,
    PAPER_THRESHOLDS,
    QualityComparison,
)
from mvbb_ros.evaluation.gripper import (
    DEFAULT_DEPTH_FACTOR,
    DEFAULT_WIDTH_FACTOR,
    ParallelJawGripper,
)
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.report import format_comparison, plot_quality_space
from mvbb_ros.evaluation.shared_data import shared_data_folder
from mvbb_ros.evaluation.spherical import DEFAULT_SPHERICAL_STEP_DEG
from mvbb_ros.evaluation.wrench import DEFAULT_CONE_EDGES, DEFAULT_FRICTION
import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()
BEGIN, END = '<!-- BEGIN GENERATED -->', '<!-- END GENERATED -->'

#: The even surface sample of each model that refined grasps are checked on (a complete scan).
SURFACE_SUFFIX = ('_vertices.npy', '_surface5k.npy')

#: name -> (mesh file, vertex cloud, units as the MANIFEST states them)
MODELS: dict[str, tuple[str, str, str]] = {
    'mug': ('graspit_mug_mesh.ply', 'graspit_mug_vertices.npy', 'mm (GraspIt!)'),
    'duck': ('rubber_duck_mesh.ply', 'rubber_duck_vertices.npy', 'unitless, ~2230 long'),
    'homer': ('homer_mesh.ply', 'homer_vertices.npy', 'unitless, 1.0 tall'),
    'bunny': ('bunny_bun_zipper.ply', 'bunny_vertices.npy', 'm (Stanford)'),
    'flask': ('graspit_flask_mesh.ply', 'graspit_flask_vertices.npy', 'mm (GraspIt!)'),
}


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    parser.add_argument('--out', type=Path, default=REPO / 'docs', help='output folder (docs/)')
    parser.add_argument('--models', nargs='+', choices=sorted(MODELS), default=list(MODELS))
    parser.add_argument(
        '--spherical-step',
        type=float,
        default=DEFAULT_SPHERICAL_STEP_DEG,
        help='spherical grid step, degrees (default 10, the paper; 20 is a quick subsample)',
    )
    parser.add_argument('--thresholds', type=float, nargs='+', default=list(PAPER_THRESHOLDS))
    parser.add_argument('--friction', type=float, default=DEFAULT_FRICTION)
    parser.add_argument('--cone-edges', type=int, default=DEFAULT_CONE_EDGES)
    parser.add_argument(
        '--contact-radius-factor',
        type=float,
        default=None,
        help='soft-contact radius / object diameter (default: finger width / 4 = 0.025)',
    )
    parser.add_argument(
        '--width-factor',
        type=float,
        default=DEFAULT_WIDTH_FACTOR,
        help='gripper opening / object diameter',
    )
    parser.add_argument(
        '--depth-factor',
        type=float,
        default=DEFAULT_DEPTH_FACTOR,
        help='finger depth / object diameter',
    )
    parser.add_argument(
        '--refine',
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also score each decomposition's hypotheses refined on the model's 5k surface "
        'sample (issue 16; default: yes)',
    )
    parser.add_argument('--json', type=Path, help='also write every summary row as JSON')
    parser.add_argument(
        '--no-docs', action='store_true', help='print only; do not touch the Markdown file'
    )
    return parser.parse_args(argv)


def claim_rows(comparison: QualityComparison) -> list[dict]:
    """Per box set, and for all box sets together: the 90 % / 1 % claim."""
    spherical = comparison.spherical
    rows = []
    for result in comparison.box_sets:
        rows.append({'set': result.name, **comparison.claim(result)})
    if spherical is not None and spherical.best_epsilon() > 0.0:
        best = max(result.best_epsilon() for result in comparison.box_sets)
        count = sum(result.candidates for result in comparison.box_sets)
        ratio = best / spherical.best_epsilon()
        fraction = count / spherical.candidates
        rows.append(
            {
                'set': 'all box sets',
                'quality_ratio': ratio,
                'candidate_ratio': fraction,
                'holds': bool(
                    ratio >= CLAIM_QUALITY_FRACTION and fraction <= CLAIM_CANDIDATE_FRACTION
                ),
            }
        )
    return rows


def markdown_section(name: str, units: str, comparison: QualityComparison, png: str) -> str:
    spherical = comparison.spherical
    lines = [f'### {name} ({units})', '', '```', comparison.describe(), '```', '']
    lines.append(format_comparison(comparison))
    lines.append('')
    if spherical is not None:
        counts = spherical.evaluation.status_counts()
        rate = spherical.candidates / max(spherical.evaluation.seconds, 1e-9)
        lines.append(
            f'Spherical outcomes: {counts["grasped"]} grasped, {counts["collision"]} finger '
            f'collisions, {counts["no_contact"]} without contact, {counts["missed"]} missed; '
            f'evaluated in {spherical.evaluation.seconds:.1f} s ({rate:.0f} grasps/s).'
        )
        lines.append('')
    lines.append(f'![{name}: (epsilon, V) of the force-closure grasps]({png})')
    lines.append('')
    return '\n'.join(lines)


def claim_table(claims: dict[str, list[dict]]) -> str:
    sets = [row['set'] for row in next(iter(claims.values()))] if claims else []
    header = ['model', *sets]
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for model, rows in claims.items():
        cells = [model]
        for row in rows:
            if row.get('holds') is None:
                cells.append('-')
                continue
            verdict = 'holds' if row['holds'] else 'fails'
            cells.append(
                f'{verdict}: {100 * row["quality_ratio"]:.1f} % with '
                f'{100 * row["candidate_ratio"]:.2f} %'
            )
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def write_docs(path: Path, generated: str) -> None:
    """Replace the generated part of `path` (or create the file with it)."""
    block = f'{BEGIN}\n\n{generated.strip()}\n\n{END}'
    if path.exists():
        text = path.read_text()
        if BEGIN in text and END in text:
            head, rest = text.split(BEGIN, 1)
            _, tail = rest.split(END, 1)
            text = head + block + tail
        else:
            text = text.rstrip() + '\n\n' + block + '\n'
    else:
        text = '# Grasp quality: box grasps against spherical grasps (paper Fig. 6)\n\n'
        text += block + '\n'
    with atomic_open(path) as handle:
        handle.write(text)


def main(argv=None) -> int:
    args = parse_args(argv)
    models_dir = args.data / 'models'
    if not models_dir.is_dir():
        print(f'shared data not found: {models_dir} (set MVBB_SHARED_DATA); skipping')
        return 0
    started = time.perf_counter()
    sections, claims, records = [], {}, {}
    for name in args.models:
        mesh_file, cloud_file, units = MODELS[name]
        target = GraspTarget.from_mesh(models_dir / mesh_file)
        points = np.load(models_dir / cloud_file).astype(np.float64)
        contact_radius = (
            None
            if args.contact_radius_factor is None
            else args.contact_radius_factor * target.diameter
        )
        gripper = ParallelJawGripper.for_object(
            target.diameter, width_factor=args.width_factor, depth_factor=args.depth_factor
        )
        surface = None
        if args.refine:
            surface = np.load(models_dir / cloud_file.replace(*SURFACE_SUFFIX)).astype(np.float64)
        comparison = compare_grasp_sets(
            target,
            points,
            refine=args.refine,
            surface=surface,
            name=name,
            gripper=gripper,
            thresholds=args.thresholds,
            spherical_step=args.spherical_step,
            friction=args.friction,
            cone_edges=args.cone_edges,
            contact_radius=contact_radius,
            progress=lambda message: print(message, flush=True),
        )
        print(comparison.describe())
        print(format_comparison(comparison, markdown=False), flush=True)
        png_name = f'grasp_quality_{name}.png'
        if not args.no_docs:
            plot_quality_space(comparison, args.out / png_name)
        sections.append(markdown_section(name, units, comparison, png_name))
        claims[name] = claim_rows(comparison)
        records[name] = comparison.to_dict() | {'claim': claims[name], 'units': units}
    total = time.perf_counter() - started
    stamp = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    command = 'python benchmarks/grasp_quality.py ' + ' '.join(
        argv if argv is not None else sys.argv[1:]
    )
    generated = '\n'.join(
        [
            '## Results',
            '',
            f'Generated by `{command.strip()}` on {stamp} in {total:.0f} s on '
            f'{platform.machine()} ({os.cpu_count()} CPUs, shared), Python '
            f'{platform.python_version()}.',
            '',
            '### The claim: best box grasp >= 90 % of the best spherical epsilon with <= 1 % '
            'of the candidates',
            '',
            'Each cell: the best epsilon of the set as a fraction of the best spherical epsilon, '
            "with the set's candidates as a fraction of the spherical candidates.",
            '',
            claim_table(claims),
            '',
            *sections,
        ]
    )
    print(claim_table(claims))
    print(f'total {total:.0f} s')
    if not args.no_docs:
        write_docs(args.out / 'grasp_quality.md', generated)
        print(f'wrote {args.out / "grasp_quality.md"}')
    if args.json is not None:
        with atomic_open(args.json) as handle:
            json.dump(records, handle, indent=2)
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
