"""
The ROS side of `mvbb demo`: a listener on the node's outputs, and the live/offline comparison.

:mod:`mvbb_ros.cli.demo` runs the demo (subprocesses, steps, printing); what needs rclpy or
messages is here, so that importing the command-line tools does not load ROS.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
import time

from geometry_msgs.msg import PoseArray
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.ros.messages import output_messages
from mvbb_ros.ros.offline import process_bag, ProcessedCloud, ProcessSummary
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

#: The node's output topics the listener records.
BOXES_TOPIC = '/decomposer/boxes'
GRASPS_TOPIC = '/decomposer/grasps'


@dataclass
class Frame:
    """What the node published for one cloud (matched by the header stamp)."""

    boxes: MarkerArray | None = None
    grasps: PoseArray | None = None
    printed: bool = False


@dataclass
class OfflineFrame:
    """The last cloud of the offline run: the cloud, its result and its index."""

    cloud: PointCloud2
    result: PipelineResult | None
    index: int


class DemoListener:
    """A node that records /decomposer/boxes and /decomposer/grasps, by header stamp."""

    def __init__(self) -> None:
        self.frames: dict[int, Frame] = {}
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('mvbb_demo_listener', context=self.context)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE
        )
        self.node.create_subscription(MarkerArray, BOXES_TOPIC, self._on_boxes, qos)
        self.node.create_subscription(PoseArray, GRASPS_TOPIC, self._on_grasps, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _frame(self, header: Header) -> Frame:
        stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        return self.frames.setdefault(stamp, Frame())

    def _on_boxes(self, message: MarkerArray) -> None:
        if message.markers:  # the first marker (DELETEALL) carries the cloud's header
            self._frame(message.markers[0].header).boxes = message

    def _on_grasps(self, message: PoseArray) -> None:
        self._frame(message.header).grasps = message

    def node_is_up(self) -> bool:
        """Tell whether the node's output topics have a publisher yet."""
        return all(self.node.count_publishers(topic) > 0 for topic in (BOXES_TOPIC, GRASPS_TOPIC))

    def complete(self) -> list[int]:
        """Return the stamps (ns) of the frames with both boxes and grasps, in order."""
        return sorted(s for s, f in self.frames.items() if f.boxes and f.grasps)

    def spin(self, seconds: float) -> None:
        """Handle incoming messages for `seconds`."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, deadline - time.monotonic())))

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def describe_frame(frame: Frame, index: int, seconds: float) -> str:
    """Return one line about what the node published for a frame `seconds` into the bag."""
    assert frame.boxes is not None and frame.grasps is not None
    cubes = [m for m in frame.boxes.markers if m.type == Marker.CUBE and m.action == Marker.ADD]
    sizes = sorted(
        (m.scale.x * m.scale.y * m.scale.z, (m.scale.x, m.scale.y, m.scale.z)) for m in cubes
    )
    line = f'frame {index}: stamp {seconds:5.2f} s, {len(cubes):2d} boxes'
    if sizes:
        largest = ' x '.join(f'{v * 100:.1f}' for v in sizes[-1][1])
        line += f' (largest {largest} cm)'
    line += f', {len(frame.grasps.poses):3d} grasps'
    if frame.grasps.poses:
        p = frame.grasps.poses[0].position
        line += f', best at ({p.x:+.3f}, {p.y:+.3f}, {p.z:+.3f}) m'
    return line


def compare_offline(
    bag_path: Path,
    processed_path: Path,
    settings: PipelineSettings,
    listener: DemoListener,
    on_row: Callable[[ProcessedCloud], None],
) -> tuple[ProcessSummary, list[int], OfflineFrame | None]:
    """
    Run `mvbb bag process` on the demo bag and compare every output with the live one.

    :param on_row: called with each row of the offline table.
    :return: the offline summary, the indices of the frames whose live and offline messages
        differ (or have no live answer), and the last frame.
    """
    last: list[OfflineFrame] = []
    differing: list[int] = []

    def compare(row: ProcessedCloud, cloud: PointCloud2, result: PipelineResult | None) -> None:
        on_row(row)
        # Compare as received: float32 fields (colours) are rounded by serialization.
        offline = {
            suffix: deserialize_message(serialize_message(message), type(message))
            for suffix, message in output_messages(result, cloud.header, settings).items()
        }
        live = listener.frames.get(row.stamp_ns)
        if live is None or live.boxes != offline['boxes'] or live.grasps != offline['grasps']:
            differing.append(row.index)
        last[:] = [OfflineFrame(cloud, result, row.index)]

    summary = process_bag(
        bag_path, processed_path, settings=settings, with_input=True, force=True, on_cloud=compare
    )
    return summary, differing, last[0] if last else None
