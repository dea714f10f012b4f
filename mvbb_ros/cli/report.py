"""
What `mvbb decompose` prints and writes of one cloud's result: plain-text tables and JSON.

:func:`print_report` prints the counts, the support plane, the leaf boxes by object and the best
grasps; :func:`result_document` is the JSON document of ``--json`` (the objects' trees, every
leaf, the grasps, the support plane and every parameter in force).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict
from typing import Any, TYPE_CHECKING

from mvbb_ros.pipeline.settings import PipelineSettings

if TYPE_CHECKING:  # the pipeline loads numba: imported when a command runs
    from mvbb_ros.pipeline.result import PipelineResult


def _format_vector(values: Iterable[float]) -> str:
    return ' '.join(f'{value:9.4f}' for value in values)


def print_report(result: PipelineResult, seconds: float, settings: PipelineSettings) -> None:
    """Print the counts, the leaf boxes (by object) and the best grasps as plain-text tables."""
    from mvbb_ros.pipeline.explain import empty_grasps_note

    grasps, counts, leaves = result.grasps, result.counts, result.leaves
    dropped = sum(len(item.decomposition.dropped_point_indices) for item in result.objects)
    print(
        f'{counts.finite} points, {counts.inliers} after filtering -> '
        f'{len(result.objects)} object(s), {len(leaves)} boxes '
        f'(t = {settings.decomposition.gain_threshold:g}, '
        f'completion {settings.view.completion}, {dropped} points dropped) '
        f'in {seconds * 1e3:.1f} ms'
    )
    for line in result.notes:
        print(f'note: {line}')
    support = result.support
    if support is not None:
        a, b, c, d = support.coefficients
        print(
            f'support plane ({"fixed" if support.fixed else "fitted"}): '
            f'{a:.4f} x {b:+.4f} y {c:+.4f} z {d:+.4f} = 0, {support.inliers} points of its fit '
            f'on it, outline of {len(support.outline)} corners'
        )
    elif result.support_note is not None:
        print(f'no support plane: {result.support_note}')
    up = 'unknown' if result.up is None else _format_vector(result.up).strip()
    print(f'up: {up} (from {result.up_source})')
    if result.cut_objects:
        numbers = ', '.join(str(index) for index in result.cut_objects)
        print(f"cut by the view's edge (their grasps last): object(s) {numbers}")
    print(f'{"obj":>3} {"box":>3} {"points":>7}  {"centre":^29}  {"extents":^29}  {"volume":>11}')
    rows = zip(leaves, result.leaf_object_indices, result.leaf_observed_counts, strict=True)
    for index, (box, obj, count) in enumerate(rows):
        print(
            f'{obj:3d} {index:3d} {count:7d}  {_format_vector(box.center)}  '
            f'{_format_vector(box.extents)}  {box.volume:11.4g}'
        )
    print(f'{len(grasps)} grasp hypotheses (best first)')
    note = '' if grasps else empty_grasps_note(result, settings)
    if note:
        print(f'no grasps: {note}')
    if grasps:
        print(
            f'{"rank":>4} {"obj":>3} {"box":>3} {"face":>4}  {"position":^29}  {"width":>8} '
            f'{"score":>6}'
        )
    for rank, grasp in enumerate(grasps[:10]):
        print(
            f'{rank:4d} {grasp.object_index:3d} {grasp.box_index:3d} {grasp.face:4d}  '
            f'{_format_vector(grasp.position)}  {grasp.width:8.4f} {grasp.score:6.3f}'
        )
    if len(grasps) > 10:
        print(f'... {len(grasps) - 10} more')


def result_document(result: PipelineResult, settings: PipelineSettings) -> dict[str, Any]:
    """
    Return the JSON document of one cloud's result.

    ``objects``: per object its decomposition's own dict
    (:meth:`~mvbb_ros.geometry.decomposition.result.Decomposition.to_dict`: the tree, the leaves by
    node index, each box) with its index, observed point count, completion (and why it was
    skipped, or None), mirror plane and how far it stands from the view's edge (``view_edge``:
    ``gap_deg`` and ``cut``; None when not measured); ``leaves``: every leaf box in the order
    grasps number them (``box_index``), with its object, node and observed point count; then the
    grasps, the support plane (``coefficients`` (a, b, c, d) of ``a x + b y + c z + d = 0`` with
    (a, b, c) the unit normal pointing up, ``outline`` corners in the cloud frame, ``inliers``;
    or None and ``support_note`` says why), the up direction used and its source, the filter
    counts and every parameter in force.
    """
    objects = []
    leaves = []
    for item in result.objects:
        entry = item.decomposition.to_dict()
        plane = item.shape.plane
        entry.update(
            index=item.index,
            observed_points=item.shape.observed,
            completion=item.shape.method,
            completion_skipped=item.shape.skipped,
            view_edge=None if item.view_edge is None else asdict(item.view_edge),
            mirror_plane=None
            if plane is None
            else {'normal': plane.normal.tolist(), 'point': plane.point.tolist()},
        )
        objects.append(entry)
        for node, count in zip(
            item.decomposition.leaf_nodes, item.leaf_observed_counts, strict=True
        ):
            leaves.append(
                {
                    'object': item.index,
                    'node': node.index,
                    'observed_points': count,
                    'box': node.box.to_dict(),
                }
            )
    return {
        'objects': objects,
        'leaves': leaves,
        'grasps': [grasp.to_dict() for grasp in result.grasps],
        'support': None
        if result.support is None
        else {
            'coefficients': list(result.support.coefficients),
            'outline': result.support.outline.tolist(),
            'inliers': result.support.inliers,
            'fixed': result.support.fixed,
        },
        'support_note': result.support_note,
        'up': None if result.up is None else list(result.up),
        'up_source': result.up_source,
        'filter_counts': asdict(result.counts),
        'parameters': settings.parameters(),
    }
