"""
The minimum-volume bounding box of a point set (numba kernels).

:mod:`~mvbb_ros.geometry.boxfit.fit` is the entry (:func:`minimum_bounding_box`, and
``fit_part`` for the decomposition's parts); it searches orientations
(:mod:`~mvbb_ros.geometry.boxfit.search`) over the 3D convex hull
(:mod:`~mvbb_ros.geometry.boxfit.hull`) with 2D hulls and rotating calipers
(:mod:`~mvbb_ros.geometry.boxfit.rectangle`). Importing this package imports none of them.
"""
