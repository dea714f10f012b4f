"""
Grasps: the paper's face-approach hypotheses, and their check and refinement on the points.

:mod:`~mvbb_ros.geometry.grasping.hypotheses` gives the hypotheses on a decomposition's boxes
(:func:`grasp_hypotheses`, :class:`Grasp`, :class:`GraspSettings`);
:mod:`~mvbb_ros.geometry.grasping.refine` checks, refines and scores them on the points
(:func:`refine_grasps`), with :mod:`~mvbb_ros.geometry.grasping.refinement_settings` (its
settings and what it knows of the view), its candidate lines
(:mod:`~mvbb_ros.geometry.grasping.candidates`), their scores
(:mod:`~mvbb_ros.geometry.grasping.scoring`) and ranking
(:mod:`~mvbb_ros.geometry.grasping.ranking`), the object's surface with normals
(:mod:`~mvbb_ros.geometry.grasping.surface`) and the pad gripper's contact check
(:mod:`~mvbb_ros.geometry.grasping.contacts`). Rules: ``docs/grasp_rules.md``. Importing this
package imports none of them.
"""
