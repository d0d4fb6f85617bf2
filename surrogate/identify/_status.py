"""``status``: a study's queues (the verify study, the run queue) and their worker jobs.

Each queue's runs are counted from its trials; its jobs are those its planner recorded
(:data:`surrogate.identify._jobs.JOBS_ATTR`), with their state now where the launcher's
commands answer here (``squeue`` …), as recorded otherwise, and the run each holds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from .._errors import InputDataError
from ..cluster import JobState, get_launcher
from ..storage._optuna import quiet_optuna
from ..storage._storage import open_storage, redacted_url, storage_errors, unstored
from ..study._spec import StudySpec, load_study
from ._jobs import JOBS_ATTR
from ._runs import runs_study_name
from ._verify import verify_study_name
from ._worker import JOB_ATTR

__all__ = ["StatusResult", "status"]


@dataclass(frozen=True)
class StatusResult:
    """Keys of ``surrogate status --json``.

    ``queues``: per queue study, its runs ``queued``, ``running``, ``finished`` (``ok``
    and ``failed`` among them) and ``given_back`` (trials of runs a worker gave back or
    that went stale, each queued again); ``jobs``: per job, its ``queue``, ``job_id``,
    ``phase`` (pending, running, ended), the scheduler's ``state`` and ``reason``,
    ``exit_code`` and ``run`` (the number of the trial it holds, else None);
    ``live``: whether the job states are the scheduler's now (else as last recorded).
    """

    study: str
    storage: str
    queues: dict[str, dict[str, int]]
    jobs: list[dict[str, Any]]
    live: bool

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def status(study: str | Path | StudySpec, *, storage: str | None = None) -> StatusResult:
    """The queues of ``study`` in ``storage`` (default: the study's) and their jobs."""
    spec = study if isinstance(study, StudySpec) else load_study(study)
    url = storage or spec.default_storage()
    missing = unstored(url, "surrogate status")
    if missing is not None:
        raise InputDataError(f"no storage at {missing}; nothing has run with it yet")
    quiet_optuna()
    with storage_errors(url):
        opened = open_storage(url)
        names = {s.study_name for s in optuna.get_all_study_summaries(opened)}
        queues, jobs, live = {}, [], True
        for name in (verify_study_name(spec), runs_study_name(spec)):
            if name not in names:
                continue
            queue = optuna.load_study(study_name=name, storage=opened)
            trials = queue.get_trials(deepcopy=False)
            queues[name] = run_counts(trials)
            found, here = _jobs(name, queue.user_attrs.get(JOBS_ATTR), trials)
            jobs += found
            live = live and here
    if not queues:
        raise InputDataError(
            f"no queue of {spec.name!r} in {redacted_url(url)} (nothing was run with "
            "--jobs, --launcher or surrogate worker); check --storage"
        )
    return StatusResult(spec.name, redacted_url(url), queues, jobs, live)


def run_counts(trials: Sequence[FrozenTrial]) -> dict[str, int]:
    """A queue's runs by state (see :class:`StatusResult`)."""
    ok = sum(t.state == TrialState.COMPLETE for t in trials)
    failed = sum(t.state == TrialState.FAIL and "reason" in t.user_attrs for t in trials)
    return {
        "queued": sum(t.state == TrialState.WAITING for t in trials),
        "running": sum(t.state == TrialState.RUNNING for t in trials),
        "finished": ok + failed,
        "ok": ok,
        "failed": failed,
        "given_back": sum(
            t.state == TrialState.FAIL and "reason" not in t.user_attrs for t in trials
        ),
    }


def _jobs(
    queue: str, record: Any, trials: Sequence[FrozenTrial]
) -> tuple[list[dict[str, Any]], bool]:
    """The recorded jobs of ``queue``, live where the launcher answers here."""
    if not isinstance(record, dict) or not record.get("jobs"):
        return [], True
    states = {job["job_id"]: job for job in record["jobs"]}
    live = True
    try:
        launcher = get_launcher(str(record.get("launcher")))
        now: list[JobState] = launcher.jobs(str(record.get("job_name")))
    except InputDataError:  # not a cluster's login node, or its commands fail
        now, live = [], False
    for job in now:  # the scheduler's state now; the exit code recorded where it has none
        if job.job_id in states:
            recorded = states[job.job_id]
            states[job.job_id] = {**job.to_json(), "exit_code": recorded.get("exit_code")}
    held = {
        str(t.system_attrs[JOB_ATTR]): t.number
        for t in trials
        if t.state == TrialState.RUNNING and JOB_ATTR in t.system_attrs
    }
    return [
        {"queue": queue, **job, "run": held.get(job["job_id"])} for job in states.values()
    ], live
