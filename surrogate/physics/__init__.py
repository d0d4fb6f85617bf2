"""The built-in full solver: pure numerics, arrays in, frozen records out."""

from ._coating import CoatingSection, bending_stiffness, plastic_moment
from ._features import F60_ANGLE_DEG, CurveFeatures, curve_features
from ._rod import RodSolution, default_mesh, solve_cantilever, solve_rod, uniform_mesh

SOLVER_VERSION = "rod-1"
"""Bump whenever a change to the solver changes its results (it keys the cache)."""

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
