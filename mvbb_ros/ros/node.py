"""
The `decomposer` node: segmented PointCloud2 in, boxes and grasp poses out.

Topics (relative names, remappable):

- ``cloud_in`` (sensor_msgs/PointCloud2), subscribed best effort, keep last 1, so the node
  always works on the newest cloud and hears reliable and best-effort publishers alike; the
  read-only parameter ``reliable_input`` makes it reliable with a deep queue for lossless
  evaluation of bags;
- ``~/boxes`` (visualization_msgs/MarkerArray): the leaf boxes (see :mod:`mvbb_ros.ros.messages`);
- ``~/tree`` (visualization_msgs/MarkerArray): the non-leaf boxes of the hierarchy;
- ``~/grasps`` (geometry_msgs/PoseArray): grasp poses, best first;
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): counts and timings, once a second.

Outputs are reliable and stamped with the input header. Every tunable is a declared parameter
(:mod:`mvbb_ros.pipeline.settings`); a change is validated, refused with a reason when bad, and the
last cloud is processed again at once so tuning on a paused bag shows its effect.
"""

from __future__ import annotations

from collections.abc import Sequence
import sys
import time
import traceback
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseArray
from mvbb_ros.pipeline.process import PipelineResult, process_cloud
from mvbb_ros.pipeline.settings import (
    PipelineSettings,
    SettingSpec,
    SPEC_BY_NAME,
    SPECS,
    validate_setting,
)
from mvbb_ros.ros.messages import diagnostic_status, output_messages
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

NODE_NAME = 'decomposer'
#: Seconds between repeats of the same kind of warning.
WARNING_THROTTLE_S = 5.0
#: Queue depth of the input with ``reliable_input`` (clouds of up to a few MB each).
RELIABLE_INPUT_DEPTH = 50

_PARAMETER_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
    list: ParameterType.PARAMETER_DOUBLE_ARRAY,
}


def parameter_descriptor(spec: SettingSpec) -> ParameterDescriptor:
    """Return the ROS descriptor of a setting: type, description, range, read-only."""
    descriptor = ParameterDescriptor(
        name=spec.name,
        type=_PARAMETER_TYPES[spec.kind],
        description=spec.description,
        read_only=spec.read_only,
    )
    low, high = spec.value_range or (None, None)
    if low is not None and high is not None and spec.kind is float:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)
        ]
    elif low is not None and high is not None and spec.kind is int:
        descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
    if spec.choices:
        descriptor.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    elif spec.vector_length:
        descriptor.additional_constraints = (
            f'{spec.vector_length} numbers, or unset / empty to turn it off'
        )
    return descriptor


def _setting_value(spec: SettingSpec, value: Any) -> Any:
    """Map a ROS parameter value to the setting's value (unset arrays are empty)."""
    if spec.kind is list:
        return [] if value is None else [float(v) for v in value]
    return value


def _our_changes(parameters: Sequence[Parameter]) -> dict[str, Any]:
    """Return the settings among `parameters` (not e.g. use_sim_time) as setting values."""
    return {
        parameter.name: _setting_value(SPEC_BY_NAME[parameter.name], parameter.value)
        for parameter in parameters
        if parameter.name in SPEC_BY_NAME
    }


class DecomposerNode(Node):
    """Decompose each incoming cloud into boxes and grasp poses (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._settings = PipelineSettings()
        # Validation runs before declaration takes effect: rclpy calls this on every declared
        # override, so a bad value in a YAML file raises at start-up with our reason.
        self.add_on_set_parameters_callback(self._validate_parameters)
        self._declare_parameters()
        self.add_post_set_parameters_callback(self._apply_parameters)

        reliable = self._settings.node.reliable_input
        input_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=RELIABLE_INPUT_DEPTH if reliable else 1,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        )
        output_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE
        )
        self._boxes_pub = self.create_publisher(MarkerArray, '~/boxes', output_qos)
        self._tree_pub = self.create_publisher(MarkerArray, '~/tree', output_qos)
        self._grasps_pub = self.create_publisher(PoseArray, '~/grasps', output_qos)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._subscription = self.create_subscription(
            PointCloud2, 'cloud_in', self._on_cloud, input_qos
        )
        self._reprocess_trigger = self.create_guard_condition(self._reprocess_last_cloud)
        self._diagnostics_timer = self.create_timer(1.0, self._publish_diagnostics)

        self._last_cloud: PointCloud2 | None = None
        self._last_result: PipelineResult | None = None
        self._last_error: str | None = None
        self._stats = {
            'clouds_received': 0,
            'clouds_processed': 0,
            'clouds_rejected': 0,
            'clouds_failed': 0,
        }
        self.get_logger().info(
            f'listening on {self._subscription.topic_name} '
            f'({"reliable" if reliable else "best effort, keep last 1"}); '
            f'gain_threshold={self._settings.decomposition.gain_threshold}, '
            f'min_points={self._settings.decomposition.min_points}'
        )

    # Parameters ----------------------------------------------------------------------------------

    def _declare_parameters(self) -> None:
        for spec in SPECS:
            default = self._settings.value(spec.name)
            if spec.kind is list and not default:
                default = Parameter.Type.DOUBLE_ARRAY  # unset: an empty array has no type
            self.declare_parameter(spec.name, default, parameter_descriptor(spec))
        values = {spec.name: self._parameter_value(spec) for spec in SPECS}
        self._settings = PipelineSettings().updated(values)

    def _parameter_value(self, spec: SettingSpec) -> Any:
        parameter = self.get_parameter_or(spec.name, Parameter(spec.name, value=None))
        return _setting_value(spec, parameter.value)

    def _validate_parameters(self, parameters: Sequence[Parameter]) -> SetParametersResult:
        """Refuse a change with a reason unless every value, and the result, is valid."""
        changes = _our_changes(parameters)
        if self._all_declared():
            try:
                self._settings.updated(changes)  # each value, then how they fit together
            except ValueError as error:
                return SetParametersResult(successful=False, reason=str(error))
        else:  # still declaring: the rest is not there yet, so check each value on its own
            for name, value in changes.items():
                reason = validate_setting(name, value)
                if reason is not None:
                    return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _all_declared(self) -> bool:
        return all(self.has_parameter(spec.name) for spec in SPECS)

    def _apply_parameters(self, parameters: Sequence[Parameter]) -> None:
        """Take accepted changes into the settings and process the last cloud again."""
        if not self._all_declared():
            return
        changes = _our_changes(parameters)
        if not changes:
            return
        self._settings = self._settings.updated(changes)
        self.get_logger().info(
            'parameters changed: ' + ', '.join(f'{k}={v}' for k, v in changes.items())
        )
        if self._last_cloud is not None:
            self._reprocess_trigger.trigger()

    @property
    def settings(self) -> PipelineSettings:
        """Return the settings in force."""
        return self._settings

    # Processing ----------------------------------------------------------------------------------

    def _on_cloud(self, cloud: PointCloud2) -> None:
        self._stats['clouds_received'] += 1
        self._last_cloud = cloud
        self._process(cloud)

    def _reprocess_last_cloud(self) -> None:
        if self._last_cloud is not None:
            self._process(self._last_cloud)

    def _process(self, cloud: PointCloud2) -> None:
        """Run the pipeline on `cloud` and publish; any failure publishes cleared outputs."""
        start = time.perf_counter()
        try:
            result = process_cloud(cloud, self._settings)
        except Exception as error:  # the node must survive any cloud, whatever goes wrong
            self._stats['clouds_failed'] += 1
            self._last_error = f'{type(error).__name__}: {error}'
            self.get_logger().error(
                f'processing failed ({self._last_error}); publishing cleared outputs\n'
                + traceback.format_exc(),
                throttle_duration_sec=WARNING_THROTTLE_S,
            )
            self._publish(cloud, None)
            return
        self._last_error = None
        if result.warning is not None:
            self._stats['clouds_rejected'] += 1
            self.get_logger().warning(
                f'{result.warning}; publishing cleared outputs',
                throttle_duration_sec=WARNING_THROTTLE_S,
            )
        else:
            self._stats['clouds_processed'] += 1
        self._last_result = result
        self._publish(cloud, result)
        self.get_logger().debug(
            f'{result.counts.finite} points -> {len(result.leaves)} boxes, '
            f'{len(result.grasps)} grasps in {(time.perf_counter() - start) * 1e3:.1f} ms'
        )

    def _publish(self, cloud: PointCloud2, result: PipelineResult | None) -> None:
        publishers = {
            'boxes': self._boxes_pub,
            'tree': self._tree_pub,
            'grasps': self._grasps_pub,
        }
        for suffix, message in output_messages(result, cloud.header, self._settings).items():
            publishers[suffix].publish(message)

    def _publish_diagnostics(self) -> None:
        result = self._last_result
        values: dict[str, object] = dict(self._stats)
        if result is not None:
            values.update(
                {
                    'input_points': result.counts.finite,
                    'filtered_points': result.counts.inliers,
                    'boxes': len(result.leaves),
                    'grasps': len(result.grasps),
                    'processing_ms': f'{result.total_ms:.2f}',
                }
            )
            values.update({f'{k}_ms': f'{v:.2f}' for k, v in result.timings_ms.items()})
        if self._last_error is not None:
            level, message = DiagnosticStatus.ERROR, f'processing failed: {self._last_error}'
        elif result is not None and result.warning is not None:
            level, message = DiagnosticStatus.WARN, result.warning
        elif result is None:
            level, message = DiagnosticStatus.OK, 'waiting for clouds'
        else:
            level, message = DiagnosticStatus.OK, f'{len(result.leaves)} boxes'
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [
            diagnostic_status(f'{self.get_name()}: decomposition', level, message, values)
        ]
        self._diagnostics_pub.publish(array)


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until SIGINT or shutdown; return 0 on a clean exit."""
    rclpy.init(args=None if args is None else list(args))
    node = None
    try:
        node = DecomposerNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
