"""
mvbb_ros: minimum-volume bounding box decomposition and grasp hypotheses.

The geometry is numpy/scipy with numba kernels, importable without ROS; :func:`process_points`
is the node's whole per-cloud pipeline (filters, decomposition, grasps) on a numpy array::

    from mvbb_ros import Box, minimum_bounding_box, decompose, grasp_hypotheses
    from mvbb_ros import PipelineSettings, process_points

``decompose(points)`` with no options is the paper's algorithm; ``process_points(points)`` uses
the node's settings (``PipelineSettings()``). The layers are described in
``docs/architecture.md``.

Huebner, Ruthotto and Kragic, "Minimum Volume Bounding Box Decomposition for Shape Approximation
in Robot Grasping", ICRA 2008.
"""

from __future__ import annotations

import importlib
from typing import Any, TYPE_CHECKING

# First: every numba kernel of the package is cached with the stamp kernel_cache.py gives it,
# and compile_time clocks the compiles of the kernels that the imports below compile.
from mvbb_ros import compile_time, kernel_cache  # noqa: F401
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition import decompose, Decomposition
from mvbb_ros.geometry.fit import minimum_bounding_box
from mvbb_ros.geometry.grasps import Grasp, grasp_hypotheses
from mvbb_ros.pipeline.settings import PipelineSettings

if TYPE_CHECKING:
    from mvbb_ros.pipeline.process import process_points

__all__ = [
    'Box',
    'Decomposition',
    'Grasp',
    'PipelineSettings',
    'decompose',
    'grasp_hypotheses',
    'minimum_bounding_box',
    'process_points',
]
__version__ = '0.1.0'


def __getattr__(name: str) -> Any:
    """
    Import :func:`process_points` on first use.

    The pipeline loads its compiled kernels (from numba's cache, or compiling them), and every
    import of a submodule runs this package first: the command line's help must not pay for it.
    """
    if name == 'process_points':
        return importlib.import_module('mvbb_ros.pipeline.process').process_points
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
