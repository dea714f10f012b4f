"""
Command-line tools: the ``mvbb`` command, the demo, and what they share.

:mod:`~mvbb_ros.cli.main` (the ``mvbb`` command's parser; what its subcommands run is in
:mod:`~mvbb_ros.cli.commands`, a result's tables and JSON in :mod:`~mvbb_ros.cli.report`),
:mod:`~mvbb_ros.cli.demo` (``mvbb demo``), :mod:`~mvbb_ros.cli.render` (pictures) and
:mod:`~mvbb_ros.cli.cloud_io` (.npy, .ply and .pcd files); the demo's scenes are
:mod:`~mvbb_ros.evaluation.synthetic`. Importing this package imports none of them.
"""
