"""Schedulers run the expensive solves: the launcher contract and its Slurm implementation.

A planner with ``--launcher NAME`` keeps worker jobs on a batch scheduler while runs
are queued in the study's storage (:class:`Fleet`); solvers and commands do not know
which launcher runs their workers. The contract (submit, poll, cancel) is
:class:`Launcher`; Slurm's is :class:`SlurmLauncher`.
"""

from ._fleet import Demand, Fleet, jobs_to_submit
from ._launcher import JobRequest, JobState, Launcher, available_launchers, get_launcher
from ._reach import check_reachable
from ._slurm import SlurmLauncher

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
