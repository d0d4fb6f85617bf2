"""The planner's worker jobs on a scheduler: submit, watch, replace, cancel.

One job runs one queued run (:mod:`surrogate.cluster._launcher`), so the rules are few:

- **demand** (:func:`jobs_to_submit`): a job for each queued run, less the jobs that will
  claim one (pending, or running and never seen holding a run: one that held one is
  leaving), with at most ``[cluster] max_jobs`` queued or running at once;
- **a job that ended otherwise than cleanly** (failed, timed out, preempted, its node
  lost, cancelled by someone else): a run it held comes back to the queue through the
  heartbeat rules (a worker given SIGTERM gives it back at once; a killed one's run goes
  stale), and the demand then asks for a new job for it. A worker that refused to
  start (exit code 2: its study file or storage) stops the study with its line, and
  so do :data:`FAILURES_IN_A_ROW` jobs in a row that ended without ever holding a run,
  with no run finished meanwhile (a job that cannot start its worker);
- **a pending job that can never start** (the launcher's ``never_starts``: over a
  partition's or an account's fixed limit): every job is cancelled and the study stops
  with one line (exit code 2);
- **leave or cancel**: between batches a job that finds no run leaves by itself (its
  worker's idle timeout) and a pending one waits for the next batch; when the study
  ends, pending jobs are cancelled and running ones given ``linger_s`` to leave
  (cancelled after), and on an error, SIGTERM or Ctrl-C every job of the name is
  cancelled at once — also those an earlier planner of the same study and storage left
  (a planner killed and started again takes them over meanwhile).

The scheduler is asked at most once every ``poll_s`` seconds.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .._errors import InputDataError, Interrupted
from .._pool import catch_signal
from ._launcher import ENDED, PENDING, RUNNING, JobRequest, JobState, Launcher

__all__ = ["FAILURES_IN_A_ROW", "Demand", "Fleet", "jobs_to_submit"]

logger = logging.getLogger(__name__)

GONE = "GONE"  # a job the scheduler no longer knows, its end unknown
FAILURES_IN_A_ROW = 4  # as a run's worker may die MAX_RETRY + 1 times before it is over
_HISTORY = 200  # jobs kept in the record a study's status shows
SOON_S = 1.0  # after a run finished, the scheduler is asked again this soon [s]


@dataclass(frozen=True)
class Demand:
    """What the queue asks of the jobs: runs queued and not claimed, the jobs holding a
    running run (their ids, as the workers wrote them), runs finished so far."""

    waiting: int
    holders: frozenset[str]
    finished: int


def jobs_to_submit(
    waiting: int, alive: Sequence[str], holders: frozenset[str], max_jobs: int
) -> int:
    """New jobs for ``waiting`` queued runs, given the ``alive`` jobs (pending or running)
    of which ``holders`` hold or held a run (one run a job: those claim none); never more
    than ``max_jobs`` alive."""
    free = sum(1 for job_id in alive if job_id not in holders)
    return max(0, min(waiting - free, max_jobs - len(alive)))


class Fleet:
    """The worker jobs of one queue (module docstring); a context manager that cancels
    them on the way out and turns SIGTERM into :class:`~surrogate.Interrupted`.

    Parameters
    ----------
    launcher, request
        The scheduler and the job every submission asks for.
    poll_s : float
        Ask the scheduler at most this often [s].
    label : str
        Names the study in log lines.
    stopped : str
        The message of the :class:`~surrogate.Interrupted` a SIGTERM raises.
    linger_s : float
        When the study ends, how long a running job (done with its run, or finding
        none) is given to leave by itself before it is cancelled [s].
    record : callable, optional
        Called with the jobs' states (a list of dicts) when they change, e.g. to write
        them into the storage for ``surrogate status``.
    progress : bool
        Log submissions and cancellations (logger ``surrogate``); ends that were not
        clean are warnings either way.
    history : sequence of JobState
        The jobs an earlier planner of the same queue recorded: taken over (those
        still alive are watched, and cancelled at the end, as this one's).
    """

    def __init__(
        self,
        launcher: Launcher,
        request: JobRequest,
        *,
        poll_s: float,
        label: str,
        stopped: str,
        linger_s: float = 0.0,
        record: Callable[[list[dict[str, Any]]], None] | None = None,
        progress: bool = True,
        history: Sequence[JobState] = (),
    ) -> None:
        self.launcher, self.request = launcher, request
        self.poll_s, self.label, self.stopped = poll_s, label, stopped
        self.linger_s = linger_s
        self.record, self.progress = record, progress
        self.history: dict[str, JobState] = {job.job_id: job for job in history}
        self.held: set[str] = set()
        self._cancelled: set[str] = set()
        self._failures = 0
        self._finished = -1
        self._next = self._last = 0.0
        self._done: int | None = None
        self._previous: Any = None
        self._signalled = False  # SIGTERM came: every look after raises it again
        self._stopping = False

    # -- the context: SIGTERM, and cancel on the way out ------------------------------------
    def __enter__(self) -> Fleet:
        if threading.current_thread() is threading.main_thread():
            self._previous = catch_signal(signal.SIGTERM, self._on_sigterm)
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        try:
            if kind is None:
                try:
                    self.finish()
                except BaseException:  # SIGTERM, Ctrl-C or an error while the jobs leave
                    self._stopping = True
                    self.cancel_all()
                    raise
            else:
                self._stopping = True
                self.cancel_all()
        finally:
            if self._previous is not None:
                signal.signal(signal.SIGTERM, self._previous)
                self._previous = None

    def _on_sigterm(self, signum: int, frame: Any) -> None:
        if self._stopping:  # cancelling already: a second SIGTERM does not cut that short
            return
        self._stopping = self._signalled = True
        raise Interrupted("SIGTERM", self.stopped)

    # -- watching ---------------------------------------------------------------------------
    def tend(self, demand: Callable[[], Demand], *, done: int | None = None) -> None:
        """Once every ``poll_s``: read the jobs, act on those that ended or can never
        start, and submit what ``demand()`` asks for. ``done`` (the runs the caller saw
        finished) brings the next look forward to :data:`SOON_S` after it changes: a
        job that finished its run leaves, and the next run need not wait for the poll.

        After a SIGTERM it raises :class:`Interrupted` again: the handler's exception can be
        lost on its way out — raised inside a PostgreSQL query, the driver's failed rollback
        replaced it and the storage's patience took that for an outage and tried again, and
        the planner ran on to exit 0 (seen once in a full suite run)."""
        if self._signalled:
            raise Interrupted("SIGTERM", self.stopped)
        now = time.monotonic()
        if done is not None and done != self._done:
            self._done, self._next = done, min(self._next, self._last + SOON_S)
        if now < self._next:
            return
        self._last, self._next = now, now + self.poll_s
        wanted = demand()
        self.held |= wanted.holders
        if wanted.finished > self._finished:
            self._finished, self._failures = wanted.finished, 0
        alive = self._refresh()
        for job in alive:
            if job.never_starts is not None:
                self.cancel_all()
                raise InputDataError(
                    f"{self.launcher.name} job {job.job_id} can never start: {job.reason} — "
                    f"{job.never_starts}; its jobs are cancelled, the runs finished are kept "
                    "(the same command resumes)"
                )
        # a job that held a run is leaving (one run a job), not about to claim one
        count = jobs_to_submit(
            wanted.waiting,
            [j.job_id for j in alive],
            frozenset(self.held),
            self.request.cluster.max_jobs,
        )
        self._submit(count, wanted.waiting)

    def _submit(self, count: int, waiting: int) -> None:
        if count <= 0:
            return
        self.request.log_dir.mkdir(parents=True, exist_ok=True)
        submitted = [self.launcher.submit(self.request) for _ in range(count)]
        for job_id in submitted:
            self.history[job_id] = JobState(job_id, PENDING, "SUBMITTED")
        if self.progress:
            logger.info(
                "[%s] %s: submitted job %s for %d queued run%s (%d alive, at most %d)",
                self.label,
                self.launcher.name,
                ", ".join(submitted),
                waiting,
                "" if waiting == 1 else "s",
                sum(j.alive for j in self.history.values()),
                self.request.cluster.max_jobs,
            )
        self._record()

    def _refresh(self, *, judge: bool = True) -> list[JobState]:
        """The jobs of the name as the scheduler lists them now; a job that ended since
        the last look is judged (:meth:`_ended`). Jobs an earlier planner left are taken
        over."""
        listed = {job.job_id: job for job in self.launcher.jobs(self.request.name)}
        changed = False
        for job_id, last in list(self.history.items()):
            if not last.alive:
                continue
            now = listed.get(job_id)
            if now is None or not now.alive:
                final = self.launcher.final(job_id) or now or JobState(job_id, ENDED, GONE)
                now = final if not final.alive else (now or final)
            changed |= now != last
            self.history[job_id] = now
            if judge and not now.alive:
                self._ended(now)
        for job_id, job in listed.items():
            if job_id not in self.history and job.alive:
                self.history[job_id], changed = job, True
        if changed:
            self._record()
        return [job for job in self.history.values() if job.alive]

    def _ended(self, job: JobState) -> None:
        """A job that ended: nothing to do if cleanly, cancelled by us, or forgotten by the
        scheduler before we saw how it ended (module docstring)."""
        if job.succeeded or job.job_id in self._cancelled or job.state == GONE:
            return
        code = "" if job.exit_code is None else f", exit code {job.exit_code}"
        logger.warning(
            "[%s] %s job %s ended %s%s; a run it held is queued again for a new job",
            self.label,
            self.launcher.name,
            job.job_id,
            job.state,
            code,
        )
        log = self.launcher.log_file(self.request, job.job_id)
        if job.exit_code == 2:
            raise InputDataError(
                f"{self.launcher.name} job {job.job_id}: the worker refused to start (exit code "
                f"2): {_last_line(log)} ({log})"
            )
        if job.job_id not in self.held:
            self._failures += 1
        if self._failures >= FAILURES_IN_A_ROW:
            self.cancel_all()
            raise InputDataError(
                f"{FAILURES_IN_A_ROW} {self.launcher.name} jobs in a row ended before their "
                f"worker took a run (the last, {job.job_id}: {job.state}{code}: "
                f"{_last_line(log)}); see {log}, and check [cluster] modules and setup"
            )

    # -- leaving, cancelling ----------------------------------------------------------------
    def finish(self) -> None:
        """The study is over: cancel the pending jobs, give the running ones ``linger_s`` to
        leave by themselves, then cancel what is left."""
        self.cancel_all(phases=(PENDING,))
        deadline = time.monotonic() + self.linger_s
        while self._alive() and time.monotonic() < deadline:
            time.sleep(min(1.0, self.poll_s))
        self.cancel_all()
        self._refresh(judge=False)  # how the last ones ended, for the record

    def _alive(self) -> list[str]:
        try:
            return [job.job_id for job in self.launcher.jobs(self.request.name) if job.alive]
        except InputDataError:  # the scheduler cannot be asked: cancel what we know of
            return []

    def cancel_all(self, phases: Sequence[str] = (PENDING, RUNNING)) -> None:
        """Cancel every job of the name that is pending or running (or in ``phases``), as
        the scheduler lists them (as last seen where it cannot be asked)."""
        try:
            states = {job.job_id: job for job in self.launcher.jobs(self.request.name)}
        except InputDataError:  # the scheduler cannot be asked: cancel what we know of
            states = dict(self.history)
        todo = sorted(
            (job_id for job_id, job in states.items() if job.phase in phases),
            key=lambda job_id: (len(job_id), job_id),
        )
        if not todo:
            return
        self._cancelled |= set(todo)
        self.launcher.cancel(todo)
        for job_id in todo:
            self.history[job_id] = JobState(job_id, ENDED, "CANCELLED", "by the planner")
        if self.progress:
            logger.info(
                "[%s] %s: cancelled job %s", self.label, self.launcher.name, ", ".join(todo)
            )
        self._record()

    def _record(self) -> None:
        if self.record is not None:
            self.record([job.to_json() for job in list(self.history.values())[-_HISTORY:]])


def _last_line(path: Path) -> str:
    """The last line a job wrote to its log (its worker's error, where it stopped on one)."""
    try:
        lines = [line.strip() for line in path.read_text(errors="replace").splitlines()]
    except OSError:
        return "no log"
    lines = [line for line in lines if line]
    return lines[-1] if lines else "an empty log"
