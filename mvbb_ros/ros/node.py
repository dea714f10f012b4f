"""
The `decomposer` node: a table-top scene's or an object's PointCloud2 in, boxes and grasps out.

Topics (relative names, remappable):

- ``cloud_in`` (sensor_msgs/PointCloud2), keep last ``input_depth`` (1), reliability from
  ``input_reliability``: ``auto`` matches the publishers (reliable while every publisher offers
  it, best effort otherwise; see :mod:`mvbb_ros.ros.input`), ``reliable`` or ``best_effort``;
  settable at runtime (the subscription is re-created);
- ``~/boxes`` (visualization_msgs/MarkerArray): the leaf boxes (see :mod:`mvbb_ros.ros.messages`);
- ``~/tree`` (visualization_msgs/MarkerArray): the inner boxes of the hierarchy (a lone
  DELETEALL when ``publish_tree`` is turned off);
- ``~/box_list`` (sensor_msgs/PointCloud2): one point per box, with its size and indices;
- ``~/grasps`` (geometry_msgs/PoseArray): grasp poses, best first;
- ``~/grasp_candidates`` (sensor_msgs/PointCloud2): one point per grasp, in the order of
  ``~/grasps``, with the opening it needs, its score and its indices;
- ``~/support`` (geometry_msgs/PolygonStamped): the outline of the table the objects stand on
  (no points when the cloud has none; ``~/boxes`` draws it too, namespace ``support``);
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): counts, input rate and QoS, age of the last
  cloud, timings; once a second on the wall clock, so also under ``use_sim_time`` without
  ``/clock``.

Outputs are reliable and transient local (keep last 1: a subscriber that comes later, such as
RViz, gets the last result) and stamped with the input header. Every tunable is a declared
parameter (:mod:`mvbb_ros.pipeline.specs`) with a typed value; a change is validated,
refused with a reason when bad, and the last cloud is processed again at once so tuning on a
paused bag shows its effect. A parameter of an unknown name (a misspelt key in a parameter file)
stops the node at start-up, naming the key and the known names.
"""

from __future__ import annotations

import array
from collections.abc import Sequence
import math
import time
import traceback
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from mvbb_ros.kernels import warm_up_logged
from mvbb_ros.pipeline.budget import FrameBudget
from mvbb_ros.pipeline.explain import empty_grasps_note
from mvbb_ros.pipeline.process import GraspMemory, process_cloud
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.settings import (
    is_ros_parameter,
    PipelineSettings,
    unknown_setting_reason,
    validate_setting,
)
from mvbb_ros.pipeline.specs import SettingSpec, SPEC_BY_NAME, SPECS
from mvbb_ros.ros.diagnostics import OverloadWatch, ReceptionLog
from mvbb_ros.ros.input import CloudInput
from mvbb_ros.ros.messages import cleared_tree, diagnostic_status, output_messages, OUTPUT_TYPES
from mvbb_ros.ros.worker import FrameWorker
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

NODE_NAME = 'decomposer'
#: Seconds between repeats of the same kind of warning (rejected clouds, failures), per node.
WARNING_THROTTLE_S = 5.0
#: Seconds (wall clock) between diagnostics.
DIAGNOSTICS_PERIOD_S = 1.0
#: QoS of every output: reliable, and transient local so that a late subscriber (RViz started
#: after the node, a grasp planner that restarts) gets the last result.
OUTPUT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

_PARAMETER_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
    list: ParameterType.PARAMETER_DOUBLE_ARRAY,
}


class UnknownParameterError(ValueError):
    """Parameters given to the node (a parameter file, ``-p``) that it does not have."""


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
            f'{spec.vector_length} numbers, or an empty array to turn it off'
        )
    return descriptor


_ARRAY_TYPES = (
    Parameter.Type.BYTE_ARRAY,
    Parameter.Type.BOOL_ARRAY,
    Parameter.Type.INTEGER_ARRAY,
    Parameter.Type.DOUBLE_ARRAY,
    Parameter.Type.STRING_ARRAY,
)


def _typed(parameter: Parameter) -> Parameter:
    """Return a parameter of a setting with the setting's own type where ROS inferred another."""
    spec = SPEC_BY_NAME.get(parameter.name)
    if spec is not None and spec.kind is list and parameter.type_ in _ARRAY_TYPES:
        return vector_parameter(parameter.name, parameter.value)
    if spec is not None and spec.kind is float and parameter.type_ is Parameter.Type.INTEGER:
        return Parameter(parameter.name, Parameter.Type.DOUBLE, float(parameter.value))
    return parameter


def vector_parameter(name: str, value: Any) -> Parameter:
    """
    Return a vector setting as a DOUBLE_ARRAY parameter when its value is numbers or empty.

    ROS reads ``[0, 0, 1]`` as integers and ``[]`` as an array of no particular type; both
    become DOUBLE_ARRAY. Anything else is returned as it is (and refused by the type check).
    """
    numbers = isinstance(value, list | tuple | array.array) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )
    if numbers:
        return Parameter(name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in value])
    return Parameter(name, value=value)


def _setting_value(spec: SettingSpec, value: Any) -> Any:
    """Map a ROS parameter value to the setting's value (unset arrays are empty)."""
    if spec.kind is list:
        return [] if value is None else list(value)
    return value


def _our_changes(parameters: Sequence[Parameter]) -> dict[str, Any]:
    """
    Return the settings among `parameters` (not e.g. use_sim_time) as setting values.

    A vector declared with its type but no value yet (see ``_declare_parameters``) is no change.
    """
    return {
        parameter.name: _setting_value(SPEC_BY_NAME[parameter.name], parameter.value)
        for parameter in parameters
        if parameter.name in SPEC_BY_NAME and parameter.value is not None
    }


#: Said once at start when ``up_direction`` is not set: what the robot loses without it.
UP_UNKNOWN_HINT = (
    'up_direction is not set: it comes from the support plane when the cloud shows a table '
    '(support_plane: auto); on a segmented object grasps may approach from below and its '
    'hidden side is a weaker guess; set it from TF (the z axis of the robot base in the '
    'cloud frame; README, "Setting up_direction")'
)


class DecomposerNode(Node):
    """Decompose each incoming cloud into boxes and grasp poses (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._settings = PipelineSettings()
        # Validation runs before declaration takes effect: rclpy calls this on every declared
        # override, so a bad value in a YAML file raises at start-up with our reason.
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_pre_set_parameters_callback(self._typed_parameters)
        self._declare_parameters()
        self._check_unknown_parameters()
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._publishers_by_suffix = {
            suffix: self.create_publisher(message_class, f'~/{suffix}', OUTPUT_QOS)
            for suffix, message_class in OUTPUT_TYPES.items()
        }
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._receptions = ReceptionLog()
        self._warned: dict[str, float] = {}  # warning kind -> when it was last logged
        self._noted_frames: set[str] = set()  # frames whose result notes were logged
        self._last_cloud: PointCloud2 | None = None
        self._last_result: PipelineResult | None = None
        self._last_error: str | None = None
        self._grasp_memory = GraspMemory()  # the last top grasp, for the hysteresis
        self._budget = FrameBudget()  # frame_time_budget: lighter settings after overruns
        self._stats = {
            'clouds_received': 0,
            'clouds_processed': 0,
            'clouds_rejected': 0,
            'clouds_failed': 0,
            'clouds_reprocessed': 0,
        }
        # Before the subscription: the first cloud must not wait for the compiler (a first run
        # compiles the kernels and says so in one line; later runs load them from the cache).
        warm_up_logged(self.get_logger().info)
        # Frames run on their own thread: services and diagnostics answer during a frame. As
        # many clouds wait for it as the input keeps (input_depth); the input takes a cloud only
        # when the worker has room. After a frame the worker takes the waiting cloud itself,
        # then wakes the executor, which waits for the next.
        self._worker = FrameWorker(
            self._run_frame,
            name='decomposer frames',
            depth=self._settings.node.input_depth,
            take=self._take_waiting,
            on_room=self._wake,
        )
        self._input = CloudInput(
            self,
            self._on_cloud,
            self._settings.node.input_reliability,
            self._settings.node.input_depth,
            ready=self._worker.has_room,
        )
        self._overload = OverloadWatch()
        # The wall clock: diagnostics go on while a bag is paused under use_sim_time.
        self._diagnostics_timer = self.create_timer(
            DIAGNOSTICS_PERIOD_S,
            self._publish_diagnostics,
            clock=Clock(clock_type=ClockType.STEADY_TIME),
        )
        if self._settings.view.up is None:
            self.get_logger().info(UP_UNKNOWN_HINT)
        self.get_logger().info(
            f'gain_threshold={self._settings.decomposition.gain_threshold}, '
            f'min_points={self._settings.decomposition.min_points}; publishing on '
            f'{self.get_fully_qualified_name()}/{{{",".join(OUTPUT_TYPES)}}}'
        )

    # Parameters ----------------------------------------------------------------------------------

    def _declare_parameters(self) -> None:
        """Declare every setting with its type and value (vectors: an empty array when unset)."""
        for spec in SPECS:
            descriptor = parameter_descriptor(spec)
            default = self._settings.value(spec.name)
            override = self._parameter_overrides.get(spec.name)
            if override is not None and spec.kind is float:  # `-p tolerance:=0` is an integer
                self._parameter_overrides[spec.name] = _typed(override)
            if spec.kind is not list:
                self.declare_parameter(spec.name, default, descriptor)
                continue
            # rclpy cannot declare an empty array with a type (it infers one from the elements),
            # and an uninitialized parameter empties every GetParameters answer that names it:
            # declare the type, then set the value, the override's if there is one.
            self.declare_parameter(
                spec.name, Parameter.Type.DOUBLE_ARRAY, descriptor, ignore_override=True
            )
            override = self._parameter_overrides.get(spec.name)
            value = default if override is None else override.value
            result = self.set_parameters([vector_parameter(spec.name, value)])[0]
            if not result.successful:
                raise InvalidParameterValueException(spec.name, value, result.reason)
        values = {
            spec.name: _setting_value(spec, self.get_parameter(spec.name).value) for spec in SPECS
        }
        self._settings = PipelineSettings().updated(values)

    def _typed_parameters(self, parameters: list[Parameter]) -> list[Parameter]:
        """Give each value its setting's type: vectors as DOUBLE_ARRAY, integers as doubles."""
        return [_typed(parameter) for parameter in parameters]

    def _check_unknown_parameters(self) -> None:
        """Refuse parameters given for this node that it does not have (misspelt keys)."""
        unknown = sorted(
            name
            for name in self._parameter_overrides
            if not self.has_parameter(name) and not is_ros_parameter(name)
        )
        if unknown:
            raise UnknownParameterError(
                '; '.join(unknown_setting_reason(name) for name in unknown)
            )

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
        before = self._settings.node
        self._settings = self._settings.updated(changes)
        after = self._settings.node
        self.get_logger().info(
            'parameters changed: ' + ', '.join(f'{k}={v}' for k, v in changes.items())
        )
        if (after.input_reliability, after.input_depth) != (
            before.input_reliability,
            before.input_depth,
        ):
            self._input.configure(after.input_reliability, after.input_depth)
            self._worker.set_depth(after.input_depth)
        if before.publish_tree and not after.publish_tree:
            header = self._last_cloud.header if self._last_cloud is not None else Header()
            self._publishers_by_suffix['tree'].publish(cleared_tree(header))
        if self._last_cloud is not None and set(changes) - {'input_reliability', 'input_depth'}:
            self._worker.again()

    @property
    def settings(self) -> PipelineSettings:
        """Return the settings in force."""
        return self._settings

    @property
    def cloud_input(self) -> CloudInput:
        """Return the input subscription (its QoS now, lost clouds, matched publishers)."""
        return self._input

    # Processing ----------------------------------------------------------------------------------

    def _on_cloud(self, cloud: PointCloud2, skipped: int) -> None:
        # The clouds replaced in the input's history before this one reached the node too.
        self._stats['clouds_received'] += 1 + skipped
        self._receptions.record(1 + skipped)
        self._last_cloud = cloud
        self._worker.submit(cloud)

    def _take_waiting(self) -> None:
        """Take the cloud that waits in the input, if any (on the worker, after a frame)."""
        try:
            self._input.take_waiting()
        except Exception as error:  # the worker must go on: the executor takes it instead
            if self._due('take'):
                self.get_logger().error(f'taking the next cloud failed: {error!r}')

    def _wake(self) -> None:
        """Wake the executor: the frame worker has room, the input may take the newest cloud."""
        executor = self.executor
        if executor is not None:
            executor.wake()

    def _run_frame(self, cloud: PointCloud2 | None) -> None:
        """Process a new cloud, or (None) the last cloud again; on the worker thread."""
        if cloud is not None:
            self._process(cloud, reprocess=False)
        elif self._last_cloud is not None:
            self._stats['clouds_reprocessed'] += 1
            self._process(self._last_cloud, reprocess=True)

    def diagnostic_counts(self) -> dict[str, int]:
        """Return the clouds counted so far, as the diagnostics report them."""
        return {
            **self._stats,
            'clouds_skipped_busy': self._worker.skipped + self._input.skipped,
            'parameter_changes_merged': self._worker.merged,
        }

    @property
    def frames(self) -> FrameWorker:
        """Return the worker of the frames, with its skipped and merged counts."""
        return self._worker

    def destroy_node(self) -> None:
        """Finish the frame in progress, then leave the graph."""
        self._worker.stop()
        super().destroy_node()

    def _process(self, cloud: PointCloud2, *, reprocess: bool) -> None:
        """Run the pipeline on `cloud` and publish; any failure publishes cleared outputs."""
        start = time.perf_counter()
        frame = str(cloud.header.frame_id)
        try:
            previous = self._grasp_memory.previous(frame)
            result = process_cloud(cloud, self._settings, previous=previous, budget=self._budget)
        except Exception as error:  # the node must survive any cloud, whatever goes wrong
            self._grasp_memory.remember(frame, None)
            self._count('clouds_failed', reprocess)
            self._last_error = f'{type(error).__name__}: {error}'
            if self._due('failed'):
                self.get_logger().error(
                    f'processing failed ({self._last_error}); publishing cleared outputs\n'
                    + traceback.format_exc()
                )
            self._publish(cloud, None)
            return
        self._last_error = None
        # Throttled, whatever the outcome: the units hint and the time budget's lighter settings.
        for kind, note in (('units', result.units_note), ('budget', result.budget_note)):
            if note is not None and self._due(kind):
                self.get_logger().warning(f"{note} (frame '{frame}')")
        if result.warning is not None:
            self._count('clouds_rejected', reprocess)
            if self._due('rejected'):
                self.get_logger().warning(f'{result.warning}; publishing cleared outputs')
        else:
            self._count('clouds_processed', reprocess)
            notes = [n for n in result.notes if n not in (result.units_note, result.budget_note)]
            if notes and frame not in self._noted_frames:
                # Once per frame: a whole model or merged views are meant to be so (nothing to
                # estimate); a wrong viewpoint needs telling once.
                self._noted_frames.add(frame)
                self.get_logger().warning(f"{'; '.join(notes)} (frame '{frame}')")
        self._last_result = result
        self._grasp_memory.remember(frame, result)
        self._publish(cloud, result)
        self.get_logger().debug(
            f'{result.counts.finite} points -> {len(result.leaves)} boxes, '
            f'{len(result.grasps)} grasps in {(time.perf_counter() - start) * 1e3:.1f} ms'
        )

    def _due(self, kind: str) -> bool:
        """Tell whether a warning of `kind` may be logged now (one per WARNING_THROTTLE_S)."""
        now = time.monotonic()
        if now - self._warned.get(kind, -math.inf) < WARNING_THROTTLE_S:
            return False
        self._warned[kind] = now
        return True

    def _count(self, outcome: str, reprocess: bool) -> None:
        """Count the outcome of a received cloud (re-processing is counted on its own)."""
        if not reprocess:
            self._stats[outcome] += 1

    def _publish(self, cloud: PointCloud2, result: PipelineResult | None) -> None:
        for suffix, message in output_messages(result, cloud.header, self._settings).items():
            self._publishers_by_suffix[suffix].publish(message)

    # Diagnostics ---------------------------------------------------------------------------------

    def _input_values(self) -> tuple[dict[str, object], list[str]]:
        """Return the input's diagnostic values and what is wrong with it (warnings)."""
        cloud_input = self._input
        publishers = cloud_input.publishers()
        age = self._receptions.age_s()
        values: dict[str, object] = {
            'input_topic': cloud_input.topic_name,
            'input_qos': cloud_input.description(),
            'input_publishers': ', '.join(
                f'{p.node} ({"reliable" if p.reliable else "best effort"})' for p in publishers
            )
            or 'none',
            'input_rate_hz': f'{self._receptions.rate_hz():.2f}',
            'last_cloud_age_s': 'never' if age is None else f'{age:.1f}',
            'clouds_lost': 'not reported by the middleware'
            if cloud_input.lost is None
            else cloud_input.lost,
            'incompatible_qos_events': cloud_input.incompatible,
        }
        problems = []
        stale_after = self._settings.node.stale_after
        waiting = self._receptions.waiting_s()
        if stale_after > 0.0 and waiting > stale_after:
            since = 'since start-up' if age is None else 'since the last one'
            problems.append(
                f'stale input: no cloud on {cloud_input.topic_name} for {waiting:.0f} s ({since}, '
                f'{len(publishers)} publisher(s))'
            )
        if cloud_input.reliability == 'reliable' and any(not p.reliable for p in publishers):
            problems.append(
                f'a best-effort publisher of {cloud_input.topic_name} is not heard by the '
                'reliable input (input_reliability: auto or best_effort hears it)'
            )
        return values, problems

    def _publish_diagnostics(self) -> None:
        result = self._last_result
        counts = self.diagnostic_counts()
        values: dict[str, object] = dict(counts)
        input_values, problems = self._input_values()
        overload = self._overload.update(counts['clouds_received'], counts['clouds_skipped_busy'])
        if overload is not None:
            problems.append(overload)
        values.update(input_values)
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
            values['up_source'] = result.up_source
            if result.up is not None:
                values['up'] = ' '.join(f'{v:.4f}' for v in result.up)
            if result.support is not None:
                values['support_plane'] = ' '.join(f'{v:.4f}' for v in result.support.coefficients)
                values['support_inliers'] = result.support.inliers
            elif result.support_note is not None:
                values['no_support_because'] = result.support_note
            note = empty_grasps_note(result, self._settings)
            if note:
                values['no_grasps_because'] = note
            if result.cut_objects:
                values['cut_by_view_edge'] = ', '.join(str(i) for i in result.cut_objects)
            if result.capped:
                values['capped'] = '; '.join(result.capped)
            if result.units_note is not None:
                values['units'] = result.units_note
            if self._budget.budget_s > 0.0:
                values['frame_budget_level'] = self._budget.level
                values['frame_budget'] = result.budget_note or 'within the budget'
            if result.budget_note is not None:
                problems.append(result.budget_note)
            skipped = [
                note
                for note in result.notes
                if note not in result.capped
                and note not in (result.units_note, result.budget_note)
            ]
            if skipped:
                values['completion_skipped'] = '; '.join(skipped)
        if self._last_error is not None:
            level, message = DiagnosticStatus.ERROR, f'processing failed: {self._last_error}'
        elif result is not None and result.warning is not None:
            level, message = DiagnosticStatus.WARN, result.warning
        elif result is None:
            level, message = DiagnosticStatus.OK, 'waiting for clouds'
        else:
            level = DiagnosticStatus.OK
            message = f'{len(result.leaves)} boxes, {len(result.grasps)} grasps'
        if problems:
            level = DiagnosticStatus.WARN if level == DiagnosticStatus.OK else level
            message = '; '.join([message, *problems])
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [
            diagnostic_status(
                f'{self.get_name()}: decomposition',
                level,
                message,
                values,
                hardware_id=self._input.topic_name,
            )
        ]
        self._diagnostics_pub.publish(array)
