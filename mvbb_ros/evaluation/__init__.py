"""
Evaluation: how good are the grasps? Our own simulator of the paper's Figure 6 experiment.

A parallel-jaw gripper on a triangle mesh, by Open3D ray casting, scored with wrench-space
measures, against the paper's spherical baseline. One module per idea, in the order they build on
each other: :mod:`~mvbb_ros.evaluation.mesh` (the object), :mod:`~mvbb_ros.evaluation.gripper`
(the hand), :mod:`~mvbb_ros.evaluation.wrench` (epsilon and V of contacts),
:mod:`~mvbb_ros.evaluation.simulation` (approach, retreat, close),
:mod:`~mvbb_ros.evaluation.spherical` (the baseline), :mod:`~mvbb_ros.evaluation.experiment`
(the comparison) and :mod:`~mvbb_ros.evaluation.report` (tables and plots). The protocol is
written out in ``docs/evaluation_protocol.md``; the results are in ``docs/grasp_quality.md``.
Nothing here is taken from GraspIt! or other grasp libraries.

:mod:`~mvbb_ros.evaluation.camera` is the virtual depth camera (pinhole ray casting with sensor
noise) that the demo scenes (:mod:`~mvbb_ros.evaluation.synthetic`) and the single-view
benchmark render with. The single-view ground
truth (issues 15 and 16, ``benchmarks/views.py``, ``docs/single_views.md``):
:mod:`~mvbb_ros.evaluation.views` (whole meshes on a table, their views, the real scans),
:mod:`~mvbb_ros.evaluation.coverage` (boxes against the whole mesh) and
:mod:`~mvbb_ros.evaluation.grasp_judge` (does a grasp hold on it; steadiness).
:mod:`~mvbb_ros.evaluation.shared_data` finds the shared real data for the benchmarks and tests.
"""
