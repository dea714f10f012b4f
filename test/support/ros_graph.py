"""
Test helpers for end-to-end tests through a real rclpy graph.

A :class:`Graph` holds one rclpy context with the node under test and a probe node that
publishes clouds and records what comes back; `spin_until` spins both until a condition holds.
A :class:`CloudSource` publishes clouds from another process (``cloud_source.py``), through the
middleware's real transport.
"""

from __future__ import annotations

from collections.abc import Callable
import os
from pathlib import Path
import select
import subprocess
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PolygonStamped, PoseArray
from mvbb_ros.ros.node import DecomposerNode
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray


class Graph:
    """A private rclpy context with the decomposer and a probe node on one executor."""

    def __init__(self, parameter_overrides: list | None = None) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.node = DecomposerNode(
            context=self.context, parameter_overrides=parameter_overrides or []
        )
        self.probe = Node('probe', context=self.context)
        self.boxes: list[MarkerArray] = []
        self.trees: list[MarkerArray] = []
        self.grasps: list[PoseArray] = []
        self.candidates: list[PointCloud2] = []
        self.box_lists: list[PointCloud2] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.supports: list[PolygonStamped] = []
        reliable = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )
        recorded = (
            (MarkerArray, '/decomposer/boxes', self.boxes),
            (MarkerArray, '/decomposer/tree', self.trees),
            (PoseArray, '/decomposer/grasps', self.grasps),
            (PointCloud2, '/decomposer/grasp_candidates', self.candidates),
            (PointCloud2, '/decomposer/box_list', self.box_lists),
            (DiagnosticArray, '/diagnostics', self.diagnostics),
            (PolygonStamped, '/decomposer/support', self.supports),
        )
        for message_class, topic, messages in recorded:
            self.probe.create_subscription(message_class, topic, messages.append, reliable)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)

    def publisher(self, reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE) -> Any:
        """Return a cloud publisher on `cloud_in` with the given reliability."""
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=reliability)
        return self.probe.create_publisher(PointCloud2, 'cloud_in', qos)

    def spin_until(self, condition: Callable[[], bool], timeout_s: float = 15.0) -> bool:
        """Spin until `condition()` holds or `timeout_s` passes; return whether it held."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def answer(self, sec: int, nanosec: int = 0) -> PoseArray | None:
        """Return the last PoseArray stamped (sec, nanosec), or None."""
        for grasps in reversed(self.grasps):
            if (grasps.header.stamp.sec, grasps.header.stamp.nanosec) == (sec, nanosec):
                return grasps
        return None

    def wait_for_answer(self, sec: int, timeout_s: float) -> bool:
        """Spin until a PoseArray stamped `sec` seconds arrives; return whether it did."""
        return self.spin_until(lambda: self.answer(sec) is not None, timeout_s)

    def publish_until_answered(self, publisher: Any, cloud: PointCloud2) -> PoseArray:
        """Publish `cloud` until a PoseArray with its stamp arrives (discovery takes a moment)."""
        stamp = (cloud.header.stamp.sec, cloud.header.stamp.nanosec)
        seen = len(self.grasps)

        def answered() -> bool:
            return any(
                (g.header.stamp.sec, g.header.stamp.nanosec) == stamp for g in self.grasps[seen:]
            )

        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and not answered():
            publisher.publish(cloud)
            self.spin_until(answered, timeout_s=1.0)
        assert answered(), 'the decomposer never answered'
        return next(
            g
            for g in reversed(self.grasps)
            if (g.header.stamp.sec, g.header.stamp.nanosec) == stamp
        )

    def close(self) -> None:
        """Destroy the nodes and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.probe.destroy_node()
        rclpy.try_shutdown(context=self.context)


class CloudSource:
    """
    A cloud publisher in another process (``test/cloud_source.py``), driven through its stdin.

    :param reliability: ``reliable`` or ``best_effort``.
    :param depth: the publisher's keep-last depth.
    :param topic: the topic it publishes on.
    :param environment: variables to set in its environment (a middleware profile, say).
    """

    def __init__(
        self,
        reliability: str,
        depth: int = 1,
        topic: str = 'cloud_in',
        environment: dict[str, str] | None = None,
    ) -> None:
        script = Path(__file__).resolve().parent / 'cloud_source.py'
        self.process = subprocess.Popen(
            [sys.executable, str(script), reliability, str(depth), topic],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, **(environment or {})},
        )
        assert self._read(60.0) == 'ready', 'the cloud source did not start'

    def _read(self, timeout_s: float) -> str:
        assert self.process.stdout is not None
        ready, _, _ = select.select([self.process.stdout], [], [], timeout_s)
        assert ready, f'no answer from the cloud source in {timeout_s} s'
        return self.process.stdout.readline().strip()

    def _send(self, line: str) -> str:
        assert self.process.stdin is not None
        self.process.stdin.write(line + '\n')
        self.process.stdin.flush()
        return self._read(60.0)

    def publish(self, sec: int, points: int = 4000) -> None:
        """Publish one L-shaped cloud of `points` points stamped `sec` seconds."""
        assert self._send(f'publish {sec} {points}') == f'published {sec}'

    def subscription_count(self) -> int:
        """Return the subscriptions matched with the source's publisher."""
        answer = self._send('count')
        assert answer.startswith('count '), answer
        return int(answer.split()[1])

    def __enter__(self) -> CloudSource:
        return self

    def __exit__(self, *exception: object) -> None:
        self.close()

    def close(self) -> None:
        """End the process (end of its input)."""
        if self.process.stdin is not None:
            self.process.stdin.close()
        try:
            self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def set_parameter(graph: Graph, name: str, value) -> tuple[bool, str]:
    """Call the node's real SetParameters service from the probe node."""
    client = graph.probe.create_client(SetParameters, '/decomposer/set_parameters')
    assert graph.spin_until(lambda: client.service_is_ready(), timeout_s=10.0)
    request = SetParameters.Request(
        parameters=[
            ParameterMsg(name=name, value=Parameter(name, value=value).get_parameter_value())
        ]
    )
    future = client.call_async(request)
    assert graph.spin_until(future.done, timeout_s=10.0)
    result = future.result().results[0]
    graph.probe.destroy_client(client)
    return result.successful, result.reason
