"""Identify the coating of LS-DYNA ``*MAT_SEATBELT_2D`` webbing from bending tests.

The public Python API; every CLI command of ``surrogate`` is a function here
of the same name. Heavy parts (scikit-learn, pandas, Optuna) load on first use.

The packages, top down (a package imports from its own row or the rows below)::

    _cli.py → this API (here)
      → reporting/    one HTML page of what a study's storage holds (the function: report)
      → identify/     the main job: loop, verify study, workers, export
        calibration/  measurements → calibrate → compare → diagnose
      → solvers/ (builtin, CalculiX, LS-DYNA), gp/, effects/, study/, storage/
      → physics/ (the rod, the coating section, curve features)
"""

from ._errors import InputDataError, InputDataWarning, Interrupted, SolverError, SurrogateError
from ._lazy import lazy_attributes
from .physics import CurveFeatures, curve_features
from .solvers._simulate import BendingCurve, simulate
from .study._rig import Rig

_LAZY = {
    "PAPER_SPACE": ".study._space",
    "ParameterSpace": ".study._space",
    "ParameterSpec": ".study._space",
    "make_design": ".identify._doe",
    "paper_stage1_design": ".identify._doe",
    "SampleSet": ".study._samples",
    "StudySpec": ".study._spec",
    "load_study": ".study._spec",
    "DoeResult": ".identify",
    "FitResult": ".identify",
    "PredictResult": ".identify",
    "doe": ".identify",
    "fit": ".identify",
    "predict": ".identify",
    "CoatingSurrogate": ".gp",
    "CalibrationResult": ".calibration",
    "calibrate": ".calibration",
    "RunResult": ".identify",
    "run": ".identify",
    "CompareResult": ".calibration",
    "DiagnosisResult": ".calibration",
    "diagnose": ".calibration",
    "compare": ".calibration",
    "ExportResult": ".identify",
    "export": ".identify",
    "StatusResult": ".identify",
    "status": ".identify",
    "ReportResult": ".reporting",
    "report": ".reporting",
    "NextTestResult": ".design",
    "next_test": ".design",
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
    "InputDataWarning",
    "Interrupted",
    "ModelState",
    "NextTestResult",
    "ParameterSpace",
    "ParameterSpec",
    "PredictResult",
    "ReportResult",
    "Rig",
    "RunResult",
    "SampleSet",
    "SolverError",
    "StatusResult",
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
    "next_test",
    "paper_stage1_design",
    "predict",
    "register_effect",
    "report",
    "run",
    "simulate",
    "status",
]

__version__ = "0.1.0"

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
