"""
Grasp hypotheses per model and threshold, before and after each filter (issue 5).

    .venv/bin/python benchmarks/grasps.py [--shared ../shared/data]

Models from the shared data, scaled to metres for the gripper: the Bunny is in metres, the
GraspIt! mug in millimetres, Homer is unitless and is taken as a 0.25 m figurine. Gripper
0.08 m wide, standoff 0.05 m; the support plane is horizontal through the lowest point along
the model's up axis (+y for all three).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

from mvbb_ros.evaluation.shared_data import shared_data_folder
from mvbb_ros.geometry.decomposition.tree import decompose
from mvbb_ros.geometry.grasping.hypotheses import grasp_filter_counts, grasp_hypotheses
import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
#: (file, metres per model unit).
MODELS = {
    'bunny': ('bunny_vertices.npy', 1.0),
    'mug': ('graspit_mug_vertices.npy', 0.001),
    'homer': ('homer_vertices.npy', 0.25),
}
THRESHOLDS = (0.90, 0.94, 0.98)
UP = np.array([0.0, 1.0, 0.0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--shared', type=Path, default=shared_data_folder())
    args = parser.parse_args()
    models = args.shared / 'models'
    if not models.is_dir():
        print(f'shared models not found in {models}', file=sys.stderr)
        return 1
    header = (
        f'{"model":<6} {"t":>5} {"boxes":>5} {"hyp":>5} {"occl":>5} {"width":>5} '
        f'{"support":>7}  {"ms":>6}'
    )
    print(header)
    for name, (file, metres) in MODELS.items():
        points = np.load(models / file).astype(np.float64) * metres
        plane = np.array([*UP, -float(np.min(points @ UP))])
        for threshold in THRESHOLDS:
            decomposition = decompose(points, gain_threshold=threshold)
            options = {'gripper_max_width': 0.08, 'standoff': 0.05, 'support_plane': plane}
            start = time.perf_counter()
            grasps = grasp_hypotheses(decomposition, **options)
            milliseconds = (time.perf_counter() - start) * 1e3
            stats = grasp_filter_counts(decomposition, **options)
            assert len(grasps) == stats.after_support
            print(
                f'{name:<6} {threshold:5.2f} {stats.boxes:5d} {stats.hypotheses:5d} '
                f'{stats.after_occlusion:5d} {stats.after_width:5d} {stats.after_support:7d}  '
                f'{milliseconds:6.1f}'
            )
    print('hyp: 24 per box; then after the occlusion, width and support filters, in that order')
    return 0


if __name__ == '__main__':
    sys.exit(main())
