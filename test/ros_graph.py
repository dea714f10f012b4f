"""
Test helpers for end-to-end tests through a real rclpy graph.

A :class:`Graph` holds one rclpy context with the node under test and a probe node that
publishes clouds and records what comes back; `spin_until` spins both until a condition holds.
"""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any

from geometry_msgs.msg import PoseArray
from mvbb_ros.ros.node import DecomposerNode
import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray


def l_shape_points(seed: int = 0, count: int = 4000) -> np.ndarray:
    """
    Return points on the surface of an L-shaped object of two boxes (metres, ~0.1-0.2 m).

    The fit-and-split decomposition splits it into two boxes at the default threshold.
    """
    rng = np.random.default_rng(seed)
    parts = []
    for low, high in (((0.0, 0.0, 0.0), (0.20, 0.05, 0.05)), ((0.0, 0.0, 0.0), (0.05, 0.05, 0.2))):
        low_corner, high_corner = np.array(low), np.array(high)
        samples = rng.uniform(low_corner, high_corner, size=(count // 2, 3))
        axis = rng.integers(0, 3, size=len(samples))
        side = rng.integers(0, 2, size=len(samples))
        samples[np.arange(len(samples)), axis] = np.where(
            side == 1, high_corner[axis], low_corner[axis]
        )
        parts.append(samples)
    return np.concatenate(parts) + np.array([0.1, -0.05, 0.6])


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
        reliable = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )
        self.probe.create_subscription(
            MarkerArray, '/decomposer/boxes', self.boxes.append, reliable
        )
        self.probe.create_subscription(
            MarkerArray, '/decomposer/tree', self.trees.append, reliable
        )
        self.probe.create_subscription(
            PoseArray, '/decomposer/grasps', self.grasps.append, reliable
        )
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
