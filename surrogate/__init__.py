"""Identify the coating of LS-DYNA ``*MAT_SEATBELT_2D`` webbing from bending tests.

The public Python API; every CLI command of ``surrogate`` is a function here
of the same name. Heavy parts (scikit-learn, pandas, Optuna) load on first use.
"""

from importlib import import_module
from typing import Any

from ._errors import InputDataError, SolverError, SurrogateError
from ._rig import Rig
from ._simulate import BendingCurve, simulate
from .physics import CurveFeatures, curve_features

_LAZY = {
    "PAPER_SPACE": "._space",
    "ParameterSpace": "._space",
    "ParameterSpec": "._space",
    "make_design": "._doe",
    "paper_stage1_design": "._doe",
    "SampleSet": "._samples",
    "StudySpec": "._study",
    "load_study": "._study",
    "DoeResult": "._surrogate_commands",
    "FitResult": "._surrogate_commands",
    "PredictResult": "._surrogate_commands",
    "doe": "._surrogate_commands",
    "fit": "._surrogate_commands",
    "predict": "._surrogate_commands",
    "CoatingSurrogate": ".gp",
    "CalibrationResult": "._calibrate",
    "calibrate": "._calibrate",
    "RunResult": "._run",
    "run": "._run",
    "CompareResult": "._compare",
    "DiagnosisResult": "._diagnose",
    "diagnose": "._diagnose",
    "compare": "._compare",
    "ExportResult": "._export",
    "export": "._export",
    "Effect": ".effects",
    "EffectParameter": ".effects",
    "ModelState": ".effects",
    "register_effect": ".effects",
    "load_plugin": ".effects",
    "available_effects": ".effects",
}

__all__ = [
    "PAPER_SPACE",
    "BendingCurve",
    "CalibrationResult",
    "CoatingSurrogate",
    "CompareResult",
    "CurveFeatures",
    "DiagnosisResult",
    "DoeResult",
    "Effect",
    "EffectParameter",
    "ExportResult",
    "FitResult",
    "InputDataError",
    "ModelState",
    "ParameterSpace",
    "ParameterSpec",
    "PredictResult",
    "Rig",
    "RunResult",
    "SampleSet",
    "SolverError",
    "StudySpec",
    "SurrogateError",
    "available_effects",
    "calibrate",
    "compare",
    "curve_features",
    "diagnose",
    "doe",
    "export",
    "fit",
    "load_plugin",
    "load_study",
    "make_design",
    "paper_stage1_design",
    "predict",
    "register_effect",
    "run",
    "simulate",
]

__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'surrogate' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
