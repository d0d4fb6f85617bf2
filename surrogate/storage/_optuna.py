"""What the package says to Optuna: a parameter space's distributions, and quiet.

The one converter from :class:`surrogate.study.ParameterSpace` to Optuna
distributions (the verify study, the workers, the calibration's search and its
record all ask with these), and the one place that silences Optuna's messages
that tell a user nothing.
"""

from __future__ import annotations

import logging
import warnings
from typing import Any

import optuna

__all__ = ["distributions", "quiet_optuna", "suggest"]


def distributions(space: Any) -> dict[str, optuna.distributions.BaseDistribution]:
    """``{name: FloatDistribution(low, high, log)}`` for every parameter of ``space``
    (a :class:`~surrogate.study.ParameterSpace`), in its order."""
    return {p.name: optuna.distributions.FloatDistribution(p.low, p.high, log=p.log) for p in space}


def suggest(trial: optuna.Trial, space: Any) -> dict[str, float]:
    """Every parameter of ``space`` suggested on ``trial`` (a queued trial: its fixed values)."""
    return {p.name: trial.suggest_float(p.name, p.low, p.high, log=p.log) for p in space}


def quiet_optuna() -> None:
    """Optuna's INFO lines off; warnings that say nothing to a user silenced:

    - metric names are "experimental" since Optuna 3.2 and stable in use;
    - "Heartbeat of storage is supposed to be used with Study.optimize": the
      workers ask and tell trials themselves and keep the heartbeat with a thread
      of their own (:mod:`surrogate.identify._worker`), which is what it warns of.
    """
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    logging.getLogger("optuna").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings(
        "ignore", message="Heartbeat of storage is supposed to be used with Study.optimize"
    )
