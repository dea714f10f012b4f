"""The node's frames off the executor: services answer during a frame, at most input_depth wait."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import threading

from mvbb_ros.ros.diagnostics import OverloadWatch
from mvbb_ros.ros.encode import create_cloud_xyz
import mvbb_ros.ros.node
from mvbb_ros.ros.worker import FrameWorker
import pytest
from rcl_interfaces.srv import ListParameters, SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from support.ros_graph import Graph
from support.shapes import l_shape_points


class Blocking:
    """A frame function that waits for a release, recording what it was given."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.started = threading.Event()
        self.calls: list[object] = []

    def __call__(self, cloud: object) -> None:
        self.calls.append(cloud)
        self.started.set()
        assert self.release.wait(30.0)


@contextmanager
def busy_worker(depth: int = 1) -> Iterator[tuple[Blocking, FrameWorker]]:
    """Yield a worker of `depth` whose frame function is busy with a cloud named 'first'."""
    frame = Blocking()
    worker = FrameWorker(frame, depth=depth)
    try:
        worker.submit('first')
        assert frame.started.wait(10.0)
        yield frame, worker
    finally:
        frame.release.set()
        worker.stop()


def finish(frame: Blocking, worker: FrameWorker) -> list[object]:
    """Release the busy frame, wait for the worker to go idle, return what it processed."""
    frame.release.set()
    assert worker.wait_idle(10.0)
    return frame.calls


def test_clouds_arriving_during_a_frame_replace_each_other_and_are_counted():
    with busy_worker() as (frame, worker):
        for name in ('second', 'third', 'fourth'):
            worker.submit(name)
        worker.again()  # a new cloud waits: it is processed with the new settings anyway
        assert finish(frame, worker) == ['first', 'fourth']
        assert worker.skipped == 2 and worker.merged == 1


def test_settings_changed_during_a_frame_give_one_reprocessing():
    with busy_worker() as (frame, worker):
        for _ in range(50):
            worker.again()
        assert finish(frame, worker) == ['first', None] and worker.merged == 49


def test_a_deeper_worker_keeps_the_newest_clouds_in_order():
    with busy_worker(depth=3) as (frame, worker):
        for name in ('a', 'b', 'c', 'd'):
            worker.submit(name)
        assert worker.skipped == 1  # 'a', pushed out by 'd'
        assert finish(frame, worker) == ['first', 'b', 'c', 'd']


def test_room_is_fewer_clouds_than_the_depth_and_each_frame_end_calls_back():
    ends = []
    frame = Blocking()
    worker = FrameWorker(frame, depth=2, on_room=lambda: ends.append(worker.has_room()))
    try:
        assert worker.has_room()
        worker.submit('first')
        assert frame.started.wait(10.0)
        assert worker.has_room(), 'one busy of two'
        worker.submit('second')
        assert not worker.has_room(), 'one busy and one waiting: full'
        frame.release.set()
        assert worker.wait_idle(10.0)
        assert frame.calls == ['first', 'second'] and worker.has_room()
        assert len(ends) == 2  # after each frame, on the worker's thread
    finally:
        frame.release.set()
        worker.stop()


def test_a_cloud_taken_after_the_frame_goes_before_the_reprocessing():
    waiting = ['newest']
    frame = Blocking()
    worker = FrameWorker(frame, take=lambda: waiting and worker.submit(waiting.pop()))
    try:
        worker.submit('first')
        assert frame.started.wait(10.0)
        worker.again()  # settings changed during the frame
        assert not worker.has_room()
        frame.release.set()
        assert worker.wait_idle(10.0)
        # The new cloud has the new settings anyway: no re-processing of 'first'.
        assert frame.calls == ['first', 'newest']
    finally:
        frame.release.set()
        worker.stop()


def test_a_shallower_depth_drops_the_oldest_waiting_clouds():
    with busy_worker(depth=5) as (frame, worker):
        for name in ('a', 'b', 'c'):
            worker.submit(name)
        worker.set_depth(1)
        assert worker.depth == 1 and worker.skipped == 2
        assert finish(frame, worker) == ['first', 'c']
    with pytest.raises(ValueError, match='depth must be >= 1'):
        FrameWorker(Blocking(), depth=0)


def test_sustained_skipping_is_an_overload_and_a_burst_is_not():
    now = [0.0]
    watch = OverloadWatch(window_s=5.0, clock=lambda: now[0])
    assert watch.update(0, 0) is None
    now[0] = 1.0
    assert watch.update(3, 2) is None  # too few clouds to judge
    now[0] = 3.0
    assert 'overloaded: 6 of the last 10 clouds' in watch.update(10, 6)
    now[0] = 9.0
    assert watch.update(40, 6) is None  # keeping up again


def _cloud(sec: int):
    header = Header(frame_id='camera')
    header.stamp.sec = sec
    return create_cloud_xyz(l_shape_points(), header=header)


@pytest.mark.ros
def test_services_answer_and_changes_merge_while_a_frame_is_processed(monkeypatch):
    real_process_cloud = mvbb_ros.ros.node.process_cloud
    release, started = threading.Event(), threading.Event()
    calls = []

    def slow_first(cloud, settings, **options):
        calls.append((cloud.header.stamp.sec, settings.decomposition.gain_threshold))
        if len(calls) == 1:
            started.set()
            assert release.wait(30.0)
        return real_process_cloud(cloud, settings, **options)

    monkeypatch.setattr(mvbb_ros.ros.node, 'process_cloud', slow_first)
    graph = Graph()
    try:
        publisher = graph.publisher()
        assert graph.spin_until(lambda: publisher.get_subscription_count() > 0)
        publisher.publish(_cloud(1))
        assert graph.spin_until(started.is_set)
        # The frame is still running: the parameter services answer all the same.
        lister = graph.probe.create_client(ListParameters, '/decomposer/list_parameters')
        setter = graph.probe.create_client(SetParameters, '/decomposer/set_parameters')
        listed = lister.call_async(ListParameters.Request())
        assert graph.spin_until(listed.done, timeout_s=10.0), 'no answer during a frame'
        assert 'gain_threshold' in listed.result().result.names
        for value in (0.90, 0.92, 0.95, 0.97):
            request = SetParameters.Request(
                parameters=[Parameter('gain_threshold', value=value).to_parameter_msg()]
            )
            future = setter.call_async(request)
            assert graph.spin_until(future.done, timeout_s=10.0)
            assert future.result().results[0].successful
        received = graph.node.diagnostic_counts
        # The newer clouds reach the process (a probe hears them) but the node does not take
        # them while its frame runs: they replace each other in the input's history.
        heard: list = []
        graph.probe.create_subscription(PointCloud2, 'cloud_in', heard.append, 10)
        for sec in (2, 3, 4):
            publisher.publish(_cloud(sec))
        assert graph.spin_until(lambda: [c.header.stamp.sec for c in heard][-1:] == [4])
        graph.spin_until(lambda: False, timeout_s=0.5)  # half a second in which to take any
        assert received()['clouds_received'] == 1, 'a cloud was taken during the frame'
        assert not calls[1:], 'nothing else ran during the frame'
        release.set()
        assert graph.spin_until(lambda: graph.answer(4) is not None, timeout_s=30.0)
        assert graph.spin_until(graph.node.frames.idle, timeout_s=30.0)
        # The blocked frame, then the newest cloud with the last setting; the older clouds
        # and the earlier changes were merged away, the clouds counted from their sequence.
        assert calls == [(1, 0.94), (4, 0.97)]
        assert graph.answer(1) is not None
        assert graph.answer(2) is None and graph.answer(3) is None
        assert received()['clouds_skipped_busy'] == 2
        assert received()['clouds_received'] == 4
        assert graph.node.frames.skipped == 0, 'nothing waited in the worker'
    finally:
        release.set()
        graph.close()


@pytest.mark.ros
def test_the_frames_wait_as_deep_as_the_input_keeps():
    """input_depth is the frames' queue too: a bag played faster than the node loses nothing."""
    graph = Graph()
    try:
        assert graph.node.frames.depth == 1
        setter = graph.probe.create_client(SetParameters, '/decomposer/set_parameters')
        request = SetParameters.Request(
            parameters=[Parameter('input_depth', value=50).to_parameter_msg()]
        )
        future = setter.call_async(request)
        assert graph.spin_until(future.done, timeout_s=10.0)
        assert future.result().results[0].successful
        assert graph.node.frames.depth == 50
    finally:
        graph.close()
