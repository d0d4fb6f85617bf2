"""A study's worker jobs on a batch scheduler (``--launcher``): what a job runs, checked
before anything is written, and the fleet that keeps them.

A job runs ``surrogate worker STUDY --queue Q --max-runs 1`` (:func:`worker_request`)
with the storage URL in its environment (``SURROGATE_STORAGE``: not on a command line
others can read), so the study file and the storage are all it needs. Its name —
``[cluster] job_name_prefix`` + the study's name + a digest of the storage and queue —
is how a planner started again finds the jobs an earlier one left.
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import optuna

from ..cluster import Fleet, JobRequest, JobState, Launcher, check_reachable, get_launcher
from ..storage._storage import Patience, redacted_url
from ..study._spec import StudySpec

__all__ = [
    "JOBS_ATTR",
    "JOB_IDLE_S",
    "STORAGE_VARIABLE",
    "Launch",
    "job_name",
    "prepare_launch",
    "worker_request",
]

STORAGE_VARIABLE = "SURROGATE_STORAGE"  # `surrogate worker` reads --storage from it
JOBS_ATTR = "cluster_jobs"  # the queue study's attribute: its jobs, for `surrogate status`
JOB_IDLE_S = 5.0  # a job that finds no queued run (another took it) leaves after this


def job_name(spec: StudySpec, storage: str, queue: str) -> str:
    """``surrogate-<study>-<digest of storage and queue>``: one name per queue."""
    digest = hashlib.sha256(f"{redacted_url(storage)}|{queue}".encode()).hexdigest()[:6]
    return f"{spec.cluster.job_name_prefix}{spec.name}-{digest}"


def worker_request(
    spec: StudySpec,
    storage: str,
    *,
    queue: str,
    heartbeat_s: int,
    storage_patience_s: float,
    plugins: Sequence[str] = (),
) -> JobRequest:
    """The job that runs one queued run of ``queue`` (``verify`` or ``runs``)."""
    assert spec.path is not None  # a planner with a launcher was given a study file
    command = [
        sys.executable,
        "-m",
        "surrogate",
        "worker",
        str(spec.path.resolve()),
        *([] if queue == "verify" else ["--queue", queue]),
        "--max-runs",
        "1",
        "--idle-timeout",
        f"{JOB_IDLE_S:g}",
        "--heartbeat",
        str(heartbeat_s),
        "--storage-patience",
        f"{storage_patience_s:g}",
    ]
    for module in plugins:
        command += ["--plugin", module]
    return JobRequest(
        name=job_name(spec, storage, queue),
        command=tuple(command),
        environment={STORAGE_VARIABLE: storage},
        log_dir=spec.directory.resolve() / f"{spec.name}-jobs",
        cluster=spec.cluster,
    )


@dataclass(frozen=True)
class Launch:
    """A queue's worker jobs, checked: the launcher and the job it submits."""

    launcher: Launcher
    request: JobRequest
    storage: str

    def fleet(
        self, study: optuna.Study, *, patience: Patience, heartbeat_s: int, progress: bool
    ) -> Fleet:
        """The fleet of these jobs for the queue ``study``; their states are written into
        the study's attribute :data:`JOBS_ATTR` as they change."""
        name, url = self.launcher.name, redacted_url(self.storage)

        def record(jobs: list[dict[str, Any]]) -> None:
            value = {"launcher": name, "job_name": self.request.name, "jobs": jobs}
            patience(lambda: study.set_user_attr(JOBS_ATTR, value))

        label = study.study_name.split("/")[0]
        earlier = study.user_attrs.get(JOBS_ATTR)
        if not isinstance(earlier, dict) or earlier.get("job_name") != self.request.name:
            earlier = {}
        return Fleet(
            self.launcher,
            self.request,
            poll_s=float(heartbeat_s),
            label=label,
            stopped=f"{label!r} stopped by SIGTERM: its {name} jobs are cancelled and the "
            f"runs finished are kept in {url}; the same command resumes (nothing is solved "
            "twice)",
            linger_s=JOB_IDLE_S + heartbeat_s,
            record=record,
            progress=progress,
            history=[JobState.from_json(job) for job in earlier.get("jobs", [])],
        )


def prepare_launch(
    launcher: str | None,
    spec: StudySpec,
    storage: str,
    *,
    queue: str,
    heartbeat_s: int,
    storage_patience_s: float,
    plugins: Sequence[str] = (),
) -> Launch | None:
    """The launch of ``queue``'s jobs once the launcher accepts them and its nodes reach
    ``storage`` and the study folder (one line otherwise, before anything is written);
    None without a launcher."""
    if launcher is None:
        return None
    scheduler = get_launcher(launcher)
    request = worker_request(
        spec,
        storage,
        queue=queue,
        heartbeat_s=heartbeat_s,
        storage_patience_s=storage_patience_s,
        plugins=plugins,
    )
    folder = request.log_dir.parent
    check_reachable(storage, folder, runs_here=True)  # SQLite, in-memory: before Slurm is asked
    scheduler.check(request)
    check_reachable(storage, folder, runs_here=scheduler.runs_here(request))
    return Launch(scheduler, request, storage)
