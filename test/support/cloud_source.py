"""
A cloud publisher in its own process, driven line by line on stdin (for the graph tests).

Clouds between processes go through the middleware's real transport; within one process they
do not, so the loss of big clouds on a best-effort subscription only shows across processes.

Usage: ``python cloud_source.py RELIABILITY [DEPTH] [TOPIC]`` (``reliable`` or ``best_effort``).
It prints ``ready`` once its publisher exists, then for each line read:

- ``publish SEC POINTS`` publishes an L-shaped cloud of POINTS points stamped SEC seconds and
  prints ``published SEC``;
- ``count`` prints ``count N``, the subscriptions matched with the publisher.

It ends at the end of its input.
"""

from __future__ import annotations

import sys

from builtin_interfaces.msg import Time
from mvbb_ros.ros.encode import create_cloud_xyz
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from shapes import l_shape_points  # its folder is on the path of a script run from it

POLICIES = {'reliable': ReliabilityPolicy.RELIABLE, 'best_effort': ReliabilityPolicy.BEST_EFFORT}


def main(argv: list[str]) -> int:
    """Publish clouds as stdin says; return 0 at the end of the input."""
    reliability = POLICIES[argv[0]]
    depth = int(argv[1]) if len(argv) > 1 else 1
    topic = argv[2] if len(argv) > 2 else 'cloud_in'
    rclpy.init()
    node = rclpy.create_node('cloud_source')
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability)
    publisher = node.create_publisher(PointCloud2, topic, qos)
    print('ready', flush=True)
    for line in sys.stdin:
        words = line.split()
        if words[:1] == ['publish']:
            sec, points = int(words[1]), int(words[2])
            cloud = create_cloud_xyz(l_shape_points(sec, points), frame_id='camera')
            cloud.header.stamp = Time(sec=sec, nanosec=0)
            publisher.publish(cloud)
            print(f'published {sec}', flush=True)
        elif words[:1] == ['count']:
            print(f'count {publisher.get_subscription_count()}', flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
