"""
Single views: the objects in one cloud, and the side the sensor did not see.

:mod:`~mvbb_ros.geometry.views.objects` separates a cloud into objects;
:mod:`~mvbb_ros.geometry.views.completion` estimates an object's hidden side
(:func:`complete_view`) on the view's raster (:mod:`~mvbb_ros.geometry.views.raster`): a mirror
plane (:mod:`~mvbb_ros.geometry.views.mirror`) and samples of the inside
(:mod:`~mvbb_ros.geometry.views.fill`);
:mod:`~mvbb_ros.geometry.views.cells` bins points for neighbour searches in kernels (the
objects' clustering and the grasp surface use it). Rules: ``docs/single_views.md``. Importing
this package imports none of them.
"""
