"""Schedulers run the expensive solves: the launcher contract and its Slurm implementation.

A planner with ``--launcher NAME`` keeps worker jobs on a batch scheduler while runs
are queued in the study's storage (:class:`Fleet`); solvers and commands do not know
which launcher runs their workers. The contract (submit, poll, cancel) is
:class:`Launcher`; Slurm's is :class:`SlurmLauncher`.
"""

from .._lazy import lazy_attributes
from ._fleet import Demand, Fleet, jobs_to_submit
from ._launcher import JobRequest, JobState, Launcher, available_launchers, get_launcher
from ._slurm import SlurmLauncher

# loads the storages (Optuna, SQLAlchemy): not for every command's --launcher option
_LAZY = {"check_reachable": "._reach"}

__all__ = [
    "Demand",
    "Fleet",
    "JobRequest",
    "JobState",
    "Launcher",
    "SlurmLauncher",
    "available_launchers",
    "check_reachable",
    "get_launcher",
    "jobs_to_submit",
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
