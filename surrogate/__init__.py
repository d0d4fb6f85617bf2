"""Identify the coating of LS-DYNA ``*MAT_SEATBELT_2D`` webbing from bending tests.

The public Python API; every CLI command of ``surrogate`` is a function here
of the same name.
"""

from ._errors import InputDataError, SolverError, SurrogateError
from ._rig import Rig
from ._simulate import BendingCurve, simulate
from .physics import CurveFeatures, curve_features

__all__ = [
    "BendingCurve",
    "CurveFeatures",
    "InputDataError",
    "Rig",
    "SolverError",
    "SurrogateError",
    "curve_features",
    "simulate",
]

__version__ = "0.1.0"
