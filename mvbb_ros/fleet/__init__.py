"""
`mvbb fleet`: many bags through `mvbb bag process` at once, on Ray, with one summary.

A layer of its own above ``ros/``: it may import common, arrays, geometry, pipeline and ros, and
nothing imports it at module level (`mvbb fleet` imports it inside the command), so the node
and the demo never load Ray. :mod:`.inputs` finds the bags and the settings of a sweep;
:mod:`.tasks` is what a worker does (a bag, or a time range of a long one, through
:func:`mvbb_ros.ros.offline.process_clouds`, the code of `mvbb bag process`); :mod:`.run` puts
the work on Ray actors; :mod:`.summary` writes the per-cloud table and its picture.
"""
