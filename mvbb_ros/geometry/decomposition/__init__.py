"""
Fit-and-split (the paper's Sec. III): a box tree that approximates a shape.

:mod:`~mvbb_ros.geometry.decomposition.split` measures the cuts of one box (the split measure
theta) and finds the best; :mod:`~mvbb_ros.geometry.decomposition.tree` builds the tree
(:func:`decompose`); :mod:`~mvbb_ros.geometry.decomposition.result` holds it
(:class:`Decomposition`, :class:`DecompositionSettings`). Importing this package imports none
of them.
"""
