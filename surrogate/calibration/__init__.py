"""Calibration against measured curves: calibrate, compare, diagnose.

The rooms, in the order the data flow through them:

- ``_problem`` — the problem: parameters (the coating and each enabled effect's
  ``effect.param``), condition groups, measured points, the misfit; what the solver
  sees of a test as surrogate inputs; the study's measurements and noise level; the
  checks of the commands' options.
- ``_loop`` — the calibration's loop: the global phase (a curve surrogate,
  :mod:`surrogate.gp`, searched with Optuna, candidates verified by the full solver),
  then the local phase.
- ``_local`` — the local phase: bounded trust-region least squares with the full
  solver and its first-order test (shared by ``calibrate`` and ``diagnose``).
- ``_fidelity`` — with an external full solver, the same loop on the built-in solver
  corrected towards it, the expensive solver verifying its optimum and teaching the
  correction until a verified point is a local optimum of the corrected model.
- ``_calibrate`` — ``calibrate``: the loop run, its best verified point judged, the
  verifications recorded as trials of ``<name>/calibrate/<model>``.
- ``_determination`` — what the curves determine at a calibrated point (95 %
  intervals of D, Mp and each parameter; pure numerics).
- ``_compare`` — ``compare``: measured against model curves, per test, angle band
  and covariate, with plots.
- ``_diagnose`` — ``diagnose``: the local refits of the model plus each candidate
  effect, their recalibration, the model ladder.
- ``_statistics`` — the diagnosis's statistics in a pure module (NumPy/SciPy only):
  F-tests against the noise, the regressions on each column, BIC, the verdict rules.
- ``_synthetic`` — synthetic measured curves for tests, benchmarks and demos.
"""

from ._calibrate import CalibrationResult, calibrate
from ._compare import CompareResult, compare
from ._diagnose import DiagnosisResult, diagnose

__all__ = [
    "CalibrationResult",
    "CompareResult",
    "DiagnosisResult",
    "calibrate",
    "compare",
    "diagnose",
]
