"""
The minimum-volume bounding box of a point set (numba kernels).

:mod:`~mvbb_ros.geometry.boxfit.fit` is the entry (:func:`minimum_bounding_box`, and
``fit_part`` for the decomposition's parts); it starts from PCA and flat-cloud frames
(:mod:`~mvbb_ros.geometry.boxfit.frames`), searches orientations
(:mod:`~mvbb_ros.geometry.boxfit.search`) over the 3D convex hull
(:mod:`~mvbb_ros.geometry.boxfit.hull`), turning it about one axis at a time
(:mod:`~mvbb_ros.geometry.boxfit.turn`) with 2D hulls and rotating calipers
(:mod:`~mvbb_ros.geometry.boxfit.rectangle`), and checks every point against the frame found
(:mod:`~mvbb_ros.geometry.boxfit.enclose`). Importing this package imports none of them.
"""
