"""The pipeline gives the same result, bit for bit, with any number of workers (issue 41)."""

from __future__ import annotations

from dataclasses import fields, replace

from mvbb_ros.common.workers import workers
from mvbb_ros.evaluation.synthetic import table_top_frame
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
import pytest
from support.data import load_benchmark, require_shared_data

COUNTS = (1, 2, 3)


def with_workers(count: int, base: PipelineSettings | None = None) -> PipelineSettings:
    settings = base if base is not None else PipelineSettings()
    return replace(settings, execution=replace(settings.execution, workers=count))


def same_array(first, second) -> bool:
    first, second = np.asarray(first), np.asarray(second)
    return (
        first.dtype == second.dtype
        and first.shape == second.shape
        and first.tobytes() == second.tobytes()
    )


def same_cut(first, second) -> bool:
    if first is None or second is None:
        return first is second
    return all(
        same_array(getattr(first, name.name), getattr(second, name.name)) for name in fields(first)
    )


def assert_same_result(first: PipelineResult, second: PipelineResult, what: str) -> None:
    """Every object, box (centre, rotation, extents, points, cut, gain) and grasp, bit for bit."""
    assert first.warning == second.warning, what
    assert first.counts == second.counts, what
    assert len(first.objects) == len(second.objects), what
    for one, other in zip(first.objects, second.objects, strict=True):
        assert same_array(one.point_indices, other.point_indices), what
        assert same_array(one.shape.points, other.shape.points), what
        assert len(one.decomposition.nodes) == len(other.decomposition.nodes), what
        for node, twin in zip(one.decomposition.nodes, other.decomposition.nodes, strict=True):
            for name in ('center', 'rotation', 'extents'):
                assert same_array(getattr(node.box, name), getattr(twin.box, name)), what
            assert same_array(node.point_indices, twin.point_indices), what
            assert (node.children, node.gain, node.stop_reason) == (
                twin.children,
                twin.gain,
                twin.stop_reason,
            ), what
            assert same_cut(node.cut, twin.cut) and same_cut(node.tested_cut, twin.tested_cut), (
                what
            )
    assert len(first.grasps) == len(second.grasps), what
    for grasp, twin in zip(first.grasps, second.grasps, strict=True):
        for name in ('position', 'quaternion', 'approach', 'closing'):
            assert same_array(getattr(grasp, name), getattr(twin, name)), what
        assert (grasp.width, grasp.score, grasp.box_index, grasp.object_index, grasp.depth) == (
            twin.width,
            twin.score,
            twin.box_index,
            twin.object_index,
            twin.depth,
        ), what
    if first.refinement is not None and second.refinement is not None:
        assert first.refinement.candidates == second.refinement.candidates, what
        assert first.refinement.holding == second.refinement.holding, what


def test_shared_scans_resampled_give_the_same_result_with_any_number_of_workers():
    """Issue 41's clouds: every shared scan resampled to 300k points with 1.5 mm noise."""
    folder = require_shared_data('scans')
    bench = load_benchmark('workers')
    scans = sorted(folder.glob('*.npy'))
    assert scans, f'no scans in {folder}'
    grasped = 0
    for path in scans:
        cloud = bench.resampled(path)
        results = {count: process_points(cloud, with_workers(count)) for count in COUNTS}
        assert results[1].leaves, path.stem
        grasped += bool(results[1].grasps)
        for count in COUNTS[1:]:
            assert_same_result(results[1], results[count], f'{path.stem}, {count} workers')
    assert grasped > len(scans) // 2, 'the refinement ran on most scans'


@pytest.mark.parametrize('seed', [0, 3])
def test_a_table_top_scene_of_several_objects_gives_the_same_result(seed):
    frame = table_top_frame(seed, 4)
    points = frame.points.reshape(-1, 3)
    cloud = points[np.isfinite(points).all(axis=1)].astype(np.float32)
    results = {count: process_points(cloud, with_workers(count)) for count in COUNTS}
    assert results[1].support is not None, 'the table is found'
    assert len(results[1].objects) >= 2, 'several objects: they run at once with workers'
    for count in COUNTS[1:]:
        assert_same_result(results[1], results[count], f'table-top seed {seed}, {count} workers')
    again = process_points(cloud, with_workers(2))  # the shared pool, used again
    assert_same_result(results[1], again, 'a second call on the same pool')
    # The next frame of a stream: the previous top grasp checked again (hysteresis).
    previous = results[1].grasps[0]
    follow = {
        count: process_points(cloud, with_workers(count), previous=previous) for count in COUNTS
    }
    for count in COUNTS[1:]:
        assert_same_result(follow[1], follow[count], f'with the previous grasp, {count} workers')


def test_the_paper_settings_and_no_completion_give_the_same_result():
    """Other paths: no filters (the paper), and boxes standing for the surface (no completion)."""
    rng = np.random.default_rng(5)
    block = rng.uniform([0.0, 0.0, 0.5], [0.12, 0.05, 0.6], (3000, 3))
    post = rng.uniform([0.0, 0.0, 0.6], [0.03, 0.05, 0.75], (2000, 3))
    cloud = np.vstack([block, post])
    paper = PipelineSettings.paper()
    plain = PipelineSettings().updated({'shape_completion': 'none', 'up_direction': [0, -1, 0]})
    for base in (paper, plain):
        first = process_points(cloud, with_workers(1, base))
        assert first.leaves
        for count in COUNTS[1:]:
            assert_same_result(first, process_points(cloud, with_workers(count, base)), 'paths')


def test_one_worker_runs_on_the_calling_thread_only(monkeypatch):
    """One worker never touches a pool: the code path of a single thread."""
    import mvbb_ros.pipeline.process as process

    def no_pool(count):
        raise AssertionError(f'a pool of {count} was asked for')

    monkeypatch.setattr(process, 'workers', no_pool)
    rng = np.random.default_rng(1)
    cloud = rng.uniform([0.0, 0.0, 0.5], [0.1, 0.05, 0.6], (5000, 3))
    assert process_points(cloud, with_workers(1)).leaves
    with pytest.raises(AssertionError, match='a pool of 2'):
        process_points(cloud, with_workers(2))


def test_the_pool_is_shared_per_count_and_not_made_per_cloud():
    assert workers(2) is workers(2)
    assert workers(3) is not workers(2)
    assert workers(3).count == 3
