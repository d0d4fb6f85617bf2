"""Identify the coating of LS-DYNA ``*MAT_SEATBELT_2D`` webbing from bending tests.

The public Python API; every CLI command of ``surrogate`` is a function here
of the same name.
"""

from ._doe import make_design, paper_stage1_design
from ._errors import InputDataError, SolverError, SurrogateError
from ._rig import Rig
from ._samples import SampleSet
from ._simulate import BendingCurve, simulate
from ._space import PAPER_SPACE, ParameterSpace, ParameterSpec
from ._study import StudySpec, load_study
from ._surrogate_commands import DoeResult, FitResult, PredictResult, doe, fit, predict
from .gp import CoatingSurrogate
from .physics import CurveFeatures, curve_features

__all__ = [
    "PAPER_SPACE",
    "BendingCurve",
    "CoatingSurrogate",
    "CurveFeatures",
    "DoeResult",
    "FitResult",
    "InputDataError",
    "ParameterSpace",
    "ParameterSpec",
    "PredictResult",
    "Rig",
    "SampleSet",
    "SolverError",
    "StudySpec",
    "SurrogateError",
    "curve_features",
    "doe",
    "fit",
    "load_study",
    "make_design",
    "paper_stage1_design",
    "predict",
    "simulate",
]

__version__ = "0.1.0"
