"""The main job: find a coating that meets an F60 target in a handful of solver runs.

The flow, one module a step:

- :mod:`._doe` (design of experiments) and :mod:`._commands` (``doe``, ``fit``,
  ``predict``: sample the full solver, fit :class:`surrogate.gp.CoatingSurrogate`);
- :mod:`._loop` (``run``): an initial design, then surrogate → constrained Optuna
  search on it (:mod:`._objective`: misfit and constraints) → full-solver
  verification, until a verified point meets the target;
- :mod:`._verify`: the verify study ``<name>/verify`` — the one place that names a
  run (:func:`verification_inputs`, solver settings included), opens the study,
  queues, tells and reads back trials; used by the in-process verifier and by
- :mod:`._worker` (``worker``, ``run --jobs N``): processes on any machine that
  claim queued trials through the storage, with heartbeats and retries;
- :mod:`._runs`: the run queue ``<name>/runs`` of ``calibrate``/``diagnose --launcher``;
  :mod:`._jobs`: the worker jobs a launcher runs; :mod:`._status` (``status``);
- :mod:`._identifiability`: what a scalar target determines;
- :mod:`._export`: the verified optimum as an LS-DYNA card.
"""

from .._lazy import lazy_attributes

# The commands load on first use (scikit-learn, Optuna and pandas are slow to import), so
# the CLI's parser and ``surrogate simulate`` do not pay for them.
_LAZY = {
    "DoeResult": "._commands",
    "FitResult": "._commands",
    "PredictResult": "._commands",
    "doe": "._commands",
    "fit": "._commands",
    "predict": "._commands",
    "ExportResult": "._export",
    "export": "._export",
    "RunResult": "._loop",
    "run": "._loop",
    "WorkerResult": "._worker",
    "work": "._worker",
    "StatusResult": "._status",
    "status": "._status",
}

__all__ = [
    "DoeResult",
    "ExportResult",
    "FitResult",
    "PredictResult",
    "RunResult",
    "StatusResult",
    "WorkerResult",
    "doe",
    "export",
    "fit",
    "predict",
    "run",
    "status",
    "work",
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
