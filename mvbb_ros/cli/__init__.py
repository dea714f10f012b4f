"""
Command-line tools: the ``mvbb`` command, the demo, and what they share.

:mod:`~mvbb_ros.cli.main` (the ``mvbb`` command), :mod:`~mvbb_ros.cli.demo` (``mvbb demo``),
:mod:`~mvbb_ros.cli.render` (pictures), :mod:`~mvbb_ros.cli.cloud_io` (.npy, .ply and .pcd
files), :mod:`~mvbb_ros.cli.synthetic` (the project's own depth-camera data),
:mod:`~mvbb_ros.cli.progress` (a progress bar) and :mod:`~mvbb_ros.cli.atomic` (atomic file
writes, also used by the bag tools). Importing this package imports none of them.
"""
