"""
The ``decomposer`` executable: join the ROS graph, then load the geometry and run the node.

DDS discovery runs in the middleware's threads from the moment the process's participant
exists, which in rclpy is when the context's first node is created. Importing the node's
module loads numba, the kernels and the pipeline (most of the start); a participant created
after that and a subscription created at once race the discovery of the endpoint: the peers
see the subscription at once or, when the first announcements are missed, seconds later.
So a hidden start-up node (:data:`STARTUP_NODE`) creates the participant first, discovery is
done while the module loads, and the node's subscription is announced to peers that already
know the participant (measured in ``docs/performance.md``, start-up).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
import gc
import os
from pathlib import Path
import sys
import tempfile

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation

#: The node that creates the participant before the module loads: hidden (a leading
#: underscore), without the command line's remappings and parameters, rosout or services.
STARTUP_NODE = '_decomposer_startup'

USAGE = """\
usage: decomposer [-h] [--ros-args [-r cloud_in:=TOPIC] [-p NAME:=VALUE ...]
                  [--params-file FILE] ...]

The mvbb_ros node: segmented sensor_msgs/PointCloud2 on ~/cloud_in (remap it to your topic);
minimum-volume box decomposition and grasp poses out on ~/boxes and ~/tree (MarkerArray),
~/box_list and ~/grasp_candidates (PointCloud2), ~/grasps (PoseArray) and /diagnostics.
SIGINT stops it with exit code 0; bad parameters give exit code 1.

options:
  -h, --help  show this message and the parameters, and exit (without joining the ROS graph)

parameters (-p NAME:=VALUE; the node's defaults, as in config/decomposer.yaml):
"""


def ros_log_fallback(environment: dict[str, str] | None = None) -> tuple[Path, Path] | None:
    """
    Return ``(ROS's log folder, a writable one)`` when ROS's cannot be written, else None.

    rcl writes its log files under ``ROS_LOG_DIR``, else ``$ROS_HOME/log``, else
    ``~/.ros/log``, and refuses to start when that folder cannot be made (a read-only HOME, as
    in a read-only container). When the user chose no folder (no ``ROS_LOG_DIR``) and ROS's
    cannot be written, the node logs to a folder of its own under the temporary folder instead.
    """
    env = os.environ if environment is None else environment
    if env.get('ROS_LOG_DIR'):
        return None
    home = env.get('ROS_HOME') or str(Path(env.get('HOME') or Path.home()) / '.ros')
    folder = Path(home).expanduser() / 'log'
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            return None
    except OSError:
        return folder, Path(tempfile.gettempdir()) / f'ros_log_{os.getuid()}'


def wants_help(args: Sequence[str]) -> bool:
    """Return whether `args` ask for help (``-h`` or ``--help`` before any ``--ros-args``)."""
    ours = list(args)[: list(args).index('--ros-args')] if '--ros-args' in args else list(args)
    return '-h' in ours or '--help' in ours


def usage() -> str:
    """Return the help text: what the node does, its topics and every parameter's default."""
    from mvbb_ros.pipeline.settings import defaults
    from mvbb_ros.pipeline.settings_text import format_assignment
    from mvbb_ros.pipeline.specs import SPECS

    values = defaults()
    lines = [f'  {format_assignment(spec.name, values[spec.name])}' for spec in SPECS]
    return USAGE + '\n'.join(lines) + '\n'


@contextmanager
def ros_context(args: Sequence[str] | None) -> Iterator[None]:
    """
    Initialize rclpy with `args` for the block, and shut it down after it.

    ``with rclpy.init(args=args):`` in the later ROS 2 releases; Jazzy's ``rclpy.init`` returns
    None, so the same shape is spelled out here.
    """
    rclpy.init(args=None if args is None else list(args))
    try:
        yield
    finally:
        _shutdown()


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until SIGINT or shutdown; return 0 on a clean exit, 1 on bad parameters."""
    arguments = list(sys.argv if args is None else args)
    if wants_help(arguments[1:] if args is None else arguments):
        print(usage(), end='')
        return 0
    fallback = ros_log_fallback()
    if fallback is not None:  # rcl would stop at init; the node can run without that folder
        os.environ['ROS_LOG_DIR'] = str(fallback[1])
        print(
            f'decomposer: cannot write ROS log files in {fallback[0]} (read-only?); writing them '
            f'in {fallback[1]} (set ROS_LOG_DIR to choose)',
            file=sys.stderr,
        )
    try:
        with ros_context(arguments):
            try:
                return _run(arguments)
            except Exception:
                # SIGINT's handler shuts rclpy down on its own thread: landing while the node
                # starts, it fails whatever rclpy call comes next. That is a stop, not an error.
                if not rclpy.ok():
                    return 0
                raise
    except rclpy_implementation.RCLError as error:  # e.g. a parameter file that is not YAML
        print(f'decomposer: cannot start: {str(error).splitlines()[0]}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0


class _Executor(SingleThreadedExecutor):
    """
    rclpy's single-threaded executor, quiet when its construction fails.

    Made after SIGINT's handler has shut rclpy down, rclpy's executor raises halfway through its
    constructor, and its ``__del__`` then prints an AttributeError traceback on a clean stop.
    """

    def __del__(self) -> None:
        if hasattr(self, '_sigint_gc'):
            super().__del__()


def _run(arguments: Sequence[str]) -> int:
    """Join the graph, load the node's module, and spin the node until it is stopped."""
    # The executor before the node (whose constructor says "publishing on"): SIGINT's handler
    # may shut rclpy down at any moment, and spin then stops, where an executor made after it
    # would fail to be made.
    executor = _Executor()
    startup = rclpy.create_node(
        STARTUP_NODE,
        use_global_arguments=False,
        enable_rosout=False,
        start_parameter_services=False,
    )
    from mvbb_ros.kernels import announce_cold_start

    announce_cold_start(rclpy.logging.get_logger('decomposer').info)
    from mvbb_ros.pipeline.settings_text import unmatched_params_files
    from mvbb_ros.ros.node import DecomposerNode, NODE_NAME, UnknownParameterError

    try:
        node = DecomposerNode()
    except (
        UnknownParameterError,
        InvalidParameterValueException,
        InvalidParameterTypeException,
    ) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'bad parameters: {error}')
        return 1
    finally:
        startup.destroy_node()
    for line in unmatched_params_files(arguments, node.get_fully_qualified_name()):
        node.get_logger().warning(line)
    try:
        # What start-up loaded (numba, scipy, rclpy: some 140k objects) stays for good; frozen,
        # the garbage collector's full passes skip it instead of walking it during a cloud.
        gc.freeze()
        executor.add_node(node)
        executor.spin()
    finally:
        executor.shutdown(timeout_sec=0.0)
        node.destroy_node()
    return 0


def _shutdown() -> None:
    """Shut rclpy down unless SIGINT's handler did so first (it runs on its own thread)."""
    try:
        rclpy.try_shutdown()
    except rclpy_implementation.RCLError as error:
        if 'already called' not in str(error):
            raise


if __name__ == '__main__':
    sys.exit(main())
