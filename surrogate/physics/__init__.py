"""The built-in full solver: pure numerics, arrays in, frozen records out.

The rod and the section's moment–curvature law (:mod:`._rod`, :mod:`._coating`) load
on first use: their kernels are compiled with numba, whose import (0.3–0.7 s) a
process that never solves — ``surrogate --help``, a refused input, a worker of an
external solver — does not pay. A process pool whose parent never solved loads it in
each child that does (about 0.4 s a child) instead of once before the fork.
"""

from .._lazy import lazy_attributes
from ._features import F60_ANGLE_DEG, CurveFeatures, curve_features
from ._section import bending_stiffness, plastic_moment

SOLVER_VERSION = "rod-2"
"""Bump whenever a change to the solver changes its results (it keys the cache)."""

_LAZY = {
    "CoatingSection": "._coating",
    "RodSolution": "._rod",
    "default_mesh": "._rod",
    "solve_cantilever": "._rod",
    "solve_rod": "._rod",
    "uniform_mesh": "._rod",
}

__all__ = [
    "F60_ANGLE_DEG",
    "SOLVER_VERSION",
    "CoatingSection",
    "CurveFeatures",
    "RodSolution",
    "bending_stiffness",
    "curve_features",
    "default_mesh",
    "plastic_moment",
    "solve_cantilever",
    "solve_rod",
    "uniform_mesh",
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
