"""The launcher contract: what a planner needs from a batch scheduler (Slurm, PBS, LSF).

A planner (``surrogate run|calibrate|diagnose … --launcher NAME``) keeps worker jobs
on a scheduler while runs are queued in the study's storage. Each job runs one
``surrogate worker`` (:class:`JobRequest` ``command``): it claims one queued run, solves
it and leaves; the study file and the storage URL (in the job's environment,
``SURROGATE_STORAGE``, not on a command line) are all it needs, and nothing is written
for it into a shared folder but the scheduler's own log of the job.

A launcher is an object with these methods (:class:`Launcher`); Slurm's is
:class:`surrogate.cluster.SlurmLauncher`. Another scheduler (PBS, LSF) is a class of
the same methods registered in :data:`LAUNCHERS`:

``check(request)``
    The scheduler's tools are on PATH and it accepts the request's options, without
    submitting anything (Slurm: ``sbatch --test-only``); else an
    :class:`~surrogate.InputDataError` of one line.
``runs_here(request)``
    Whether every node a job may run on is this machine (a single-node cluster): only
    then may a storage that only this machine reaches (127.0.0.1, a journal on a local
    disk) serve the jobs (:mod:`surrogate.cluster._reach`).
``submit(request)``
    Submit one job; return its id. The job runs ``request.command`` after the
    ``[cluster]`` ``modules`` and ``setup`` lines, with ``request.environment`` added to
    its environment and ``SURROGATE_JOB_ID`` set to its id; it asks for one run's cores,
    memory and time, and the worker gets SIGTERM (a run given back) before the limit.
``jobs(name)``
    This user's jobs of that name the scheduler still lists, as :class:`JobState`.
``final(job_id)``
    How an ended job ended (exit code included), None once the scheduler forgot it.
``cancel(job_ids)``
    Cancel the jobs (the workers get SIGTERM and give their runs back).
``log_file(request, job_id)``
    Where the job's output (the worker's stdout and stderr) goes.

The planner's side — what to submit, when to replace a job, when to stop — is one
object for every launcher (:class:`surrogate.cluster.Fleet`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from .._errors import InputDataError
from ..study._cluster import ClusterSettings

__all__ = [
    "ENDED",
    "LAUNCHERS",
    "PENDING",
    "RUNNING",
    "JobRequest",
    "JobState",
    "Launcher",
    "available_launchers",
    "get_launcher",
]

PENDING, RUNNING, ENDED = "pending", "running", "ended"
JOB_ID_VARIABLE = "SURROGATE_JOB_ID"  # a worker writes it on the run it claims


@dataclass(frozen=True)
class JobRequest:
    """One worker job: its name (the planner finds its jobs by it), the worker's
    argument list, variables added to its environment, the folder of its log, and the
    ``[cluster]`` settings."""

    name: str
    command: tuple[str, ...]
    environment: Mapping[str, str] = field(default_factory=dict)
    log_dir: Path = Path(".")
    cluster: ClusterSettings = field(default_factory=ClusterSettings)


@dataclass(frozen=True)
class JobState:
    """One job as the scheduler reports it.

    ``phase`` is ``pending``, ``running`` or ``ended``; ``state`` and ``reason`` are
    the scheduler's own words (Slurm: ``PENDING``/``Priority``, ``FAILED``/
    ``NonZeroExitCode`` …); ``exit_code`` the worker's (negative: killed by that
    signal; None: not known); ``succeeded`` whether it ended as a job should (exit 0);
    ``never_starts`` what to fix when it waits for a reason it cannot leave.
    """

    job_id: str
    phase: str
    state: str
    reason: str = ""
    exit_code: int | None = None
    succeeded: bool = False
    never_starts: str | None = None

    @property
    def alive(self) -> bool:
        return self.phase != ENDED

    @classmethod
    def from_json(cls, record: dict[str, Any]) -> JobState:
        """A job as :meth:`to_json` wrote it (a planner's record in the storage)."""
        return cls(
            str(record["job_id"]),
            str(record.get("phase", ENDED)),
            str(record.get("state", "")),
            str(record.get("reason", "")),
            record.get("exit_code"),
            succeeded=record.get("state") == "COMPLETED" and record.get("exit_code") in (0, None),
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "job_id": self.job_id,
            "phase": self.phase,
            "state": self.state,
            "reason": self.reason,
            "exit_code": self.exit_code,
        }


class Launcher(Protocol):
    """The launcher contract (module docstring)."""

    name: str

    def check(self, request: JobRequest) -> None: ...

    def runs_here(self, request: JobRequest) -> bool: ...

    def submit(self, request: JobRequest) -> str: ...

    def jobs(self, name: str) -> list[JobState]: ...

    def final(self, job_id: str) -> JobState | None: ...

    def cancel(self, job_ids: Sequence[str]) -> None: ...

    def log_file(self, request: JobRequest, job_id: str) -> Path: ...


def _slurm() -> Launcher:
    from ._slurm import SlurmLauncher

    return SlurmLauncher()


LAUNCHERS = {"slurm": _slurm}
"""Launcher name → factory; ``--launcher`` offers these."""


def available_launchers() -> tuple[str, ...]:
    return tuple(LAUNCHERS)


def get_launcher(name: str) -> Launcher:
    """The launcher of that name, or a one-line error naming the ones there are."""
    if name not in LAUNCHERS:
        raise InputDataError(
            f"--launcher must be one of {', '.join(LAUNCHERS)}, got {name!r} (PBS and LSF: "
            "a launcher of the same contract, docs/guides/clusters.md)"
        )
    return LAUNCHERS[name]()
