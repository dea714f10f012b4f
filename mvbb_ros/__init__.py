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

if TYPE_CHECKING:
    from mvbb_ros.geometry.box import Box
    from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
    from mvbb_ros.geometry.decomposition.result import Decomposition
    from mvbb_ros.geometry.decomposition.tree import decompose
    from mvbb_ros.geometry.grasping.hypotheses import Grasp, grasp_hypotheses
    from mvbb_ros.pipeline.process import process_points
    from mvbb_ros.pipeline.settings import PipelineSettings

#: Each public name and the module that defines it, imported on first use.
_EXPORTS: dict[str, str] = {
    'Box': 'mvbb_ros.geometry.box',
    'Decomposition': 'mvbb_ros.geometry.decomposition.result',
    'Grasp': 'mvbb_ros.geometry.grasping.hypotheses',
    'PipelineSettings': 'mvbb_ros.pipeline.settings',
    'decompose': 'mvbb_ros.geometry.decomposition.tree',
    'grasp_hypotheses': 'mvbb_ros.geometry.grasping.hypotheses',
    'minimum_bounding_box': 'mvbb_ros.geometry.boxfit.fit',
    'process_points': 'mvbb_ros.pipeline.process',
}
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
    Import a public name's module on first use.

    Every import of a submodule runs this package first: the node's executable joins the ROS
    graph before the geometry loads (:mod:`mvbb_ros.ros.decomposer`), and the command line's
    help does not pay for numba and the kernels.
    """
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
