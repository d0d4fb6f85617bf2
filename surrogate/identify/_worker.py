"""``worker``: full-solver verification shared by many processes through a storage.

(The same loop serves the run queue of ``calibrate``/``diagnose --launcher``,
``--queue runs``, :mod:`._runs`; its rules differ only in :class:`._verify.Queue`.
A scheduler's job runs a worker with ``--max-runs 1``, :mod:`._jobs`.)

The planner (``surrogate run``) queues each candidate point as a ``WAITING``
trial of the study ``<name>/verify`` (``study.enqueue_trial`` with the hash of
its solver inputs); workers on any machine claim a waiting trial (the storage
moves it to ``RUNNING`` for exactly one of them), solve it through the result
cache and finish it with the same record the in-process loop writes. A worker
never creates a trial of its own.

Faults: a worker keeps a heartbeat on its trial; a dead worker's trial goes
stale, the next worker that looks fails it and
``RetryHeartbeatStaleTrialCallback`` queues a copy, so the run is redone once
(from the cache when the dead worker had finished solving). SIGTERM (or Ctrl-C)
during a solve fails the trial, queues its copy and exits. A solver failure is a
``FAIL`` trial with its ``reason``; the loop goes on. A database that cannot be
reached for a while (a restart, a failover) is waited for, up to the storage
patience, while the solve goes on (:class:`surrogate.storage._storage.Patience`).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import TrialState

from .._errors import InputDataError, Interrupted, SolverError, SurrogateError
from .._log import show_progress
from .._pool import (
    catch_signal,
    check_jobs,
    one_blas_thread,
    one_blas_thread_within,
    process_context,
)
from ..cluster import Demand, Fleet
from ..cluster._launcher import JOB_ID_VARIABLE
from ..solvers._batch import solve_inputs
from ..solvers._cache import ResultCache, input_hash
from ..storage._optuna import quiet_optuna
from ..storage._storage import (
    MAX_RETRY,
    STORAGE_PATIENCE_S,
    Patience,
    check_storage_patience,
    check_workers,
    open_storage,
    redacted_url,
    retry_callback,
    storage_errors,
    unreachable,
)
from ..study._spec import StudySpec, load_study
from ._verify import VERIFY, Queue, queue_lost_copies

__all__ = ["HEARTBEAT_S", "WorkerDispatcher", "WorkerResult", "work"]

logger = logging.getLogger(__name__)

Solve = Callable[[dict[str, Any]], dict[str, Any]]
POLL_S = 0.5
#: How long a worker whose solve failed waits for a stop signal before it records the
#: failure [s]. A batch scheduler's cancel signals the job's processes at once: the solver's
#: program (``srun`` and its tasks) may die of it, and its failure be returned, before the
#: worker's own SIGTERM handler has run; that failure is the cancel's, not the run's, so the
#: run is given back (seen: a run recorded failed and never solved, tests/cluster/test_slurm.py)
STOP_GRACE_S = 0.5
HEARTBEAT_S = 10
JOB_ATTR = "job"  # a trial's system attribute: the scheduler's job whose worker claimed it


@dataclass(frozen=True)
class WorkerResult:
    """Keys of ``surrogate worker --json``.

    ``runs`` counts the trials this worker (all its processes) finished,
    ``solved`` the solver runs among them (the rest came from the cache);
    ``interrupted`` names the signal that stopped it, if any.

    ``study`` and ``storage`` name the verify study and its storage; ``jobs`` the
    worker's processes; ``ok`` and ``failed`` the finished trials with and without a
    curve.
    """

    study: str
    storage: str
    jobs: int
    runs: int
    ok: int
    failed: int
    solved: int
    interrupted: str | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


# -- planning ---------------------------------------------------------------------------------
class WorkerDispatcher:
    """Verify a batch of points through the storage: queue, work or wait, collect.

    ``jobs`` local worker processes run the batch (0: only wait for workers
    started elsewhere with ``surrogate worker``; 1: this process works); a ``fleet``
    keeps worker jobs on a batch scheduler while the batch's runs are open
    (:class:`surrogate.cluster.Fleet`: the command that made it cancels them when it
    ends). ``queue`` names the rules of the queue study (:class:`._verify.Queue`: the
    verify study's, or the run queue's of ``calibrate``/``diagnose --launcher``).
    """

    def __init__(
        self,
        spec: StudySpec,
        storage: str,
        *,
        jobs: int,
        heartbeat_s: int = HEARTBEAT_S,
        storage_patience_s: float = STORAGE_PATIENCE_S,
        solve: Solve = solve_inputs,
        progress: bool = True,
        fleet: Fleet | None = None,
        queue: Queue = VERIFY,
    ) -> None:
        self.spec = spec
        self.storage = storage
        self.jobs = jobs
        self.fleet = fleet
        self.queue = queue
        self.heartbeat_s = heartbeat_s
        self.patience = Patience(storage, storage_patience_s, grace_s=3 * heartbeat_s)
        self.solve = solve
        self.progress = progress

    def __call__(
        self, study: optuna.Study, points: list[dict[str, Any]], phase: str
    ) -> dict[str, Any]:
        """Queue ``points`` (the queue's items: the verify study's points, the run queue's
        solver inputs), run or wait for them; their records by input hash."""
        keys = self.patience(lambda: self.queue.enqueue(study, self.spec, points, phase))
        if self.jobs > 0:
            self._work(study, keys, phase)
        elif self.progress and self.fleet is None:
            logger.info(
                "[%s] %s: %d runs queued in %s; waiting for `surrogate worker` processes",
                self.spec.name,
                phase,
                len(keys),
                self.storage,
            )
        return self._wait(study, keys, phase)

    def _work(self, study: optuna.Study, keys: list[str], phase: str) -> None:
        """The local workers, until the batch's runs are over or given back by a signal.

        A worker process that died left its trial RUNNING; the next round's workers find
        it stale, fail it and redo its copy, so a round is started again while runs are
        open (a run whose worker dies ``MAX_RETRY + 1`` times is over, as failed), in
        worker processes (a solve that kills its process is not run in the planner's).
        Before, the planner waited for ever for the copy, which nothing here would run.
        Runs still open after ``MAX_RETRY + 1`` rounds stop the planner with one line."""

        def open_runs() -> set[str]:
            return set(keys) - set(self.patience(lambda: self.queue.finished(study, keys)))

        died = None
        for _ in range(MAX_RETRY + 1):
            todo = open_runs()
            if not todo:
                return
            least = 1 if died is None else 2  # 1: one point in this process, no start-up cost
            done = work(
                self.spec,
                storage=self.storage,
                jobs=max(least, min(self.jobs, len(todo))),
                heartbeat_s=self.heartbeat_s,
                idle_timeout_s=0.0,
                storage_patience_s=self.patience.patience_s,
                storage_reached=True,
                solve=self.solve,
                progress=False,
                queue=self.queue.name,
            )
            if done.interrupted in _SIGNAL_NAMES:
                raise Interrupted(
                    done.interrupted,
                    f"{phase} of {self.spec.name!r} stopped by {done.interrupted}: the runs "
                    f"finished are kept in {redacted_url(self.storage)}; the same command "
                    "resumes the plan (nothing is solved twice)",
                )
            if done.interrupted is None:
                return
            died = done.interrupted
            logger.warning("[%s] %s: %s; its run is redone", self.spec.name, phase, died)
        todo = open_runs()
        if todo:
            raise SolverError(
                f"{phase} of {self.spec.name!r}: {len(todo)} runs still open after "
                f"{MAX_RETRY + 1} rounds of local worker processes ({died}); start "
                f"`surrogate worker` processes on {redacted_url(self.storage)}, or run the "
                "same command again (the runs finished are kept)"
            )

    def _wait(self, study: optuna.Study, keys: list[str], phase: str) -> dict[str, Any]:
        """Until every run of ``keys`` is over; says what it waits for every heartbeat."""
        wanted, said = set(keys), time.monotonic()
        judge = _StaleJudge(self.patience, self.heartbeat_s)
        while True:
            records = self.patience(lambda: self.queue.finished(study, wanted))
            if len(records) == len(wanted):
                return records
            judge(study)
            if self.fleet is not None:
                self.fleet.tend(lambda: self._demand(study), done=len(records))
            if self.progress and time.monotonic() - said >= self.heartbeat_s:
                said = time.monotonic()
                open_keys = wanted - records.keys()
                trials = self.patience(lambda: study.get_trials(deepcopy=False))
                states = [t.state for t in trials if t.user_attrs.get("input_hash") in open_keys]
                logger.info(
                    "[%s] %s: waiting for %d of %d runs (%d queued, %d running)",
                    self.spec.name,
                    phase,
                    len(open_keys),
                    len(wanted),
                    states.count(TrialState.WAITING),
                    states.count(TrialState.RUNNING),
                )
            time.sleep(POLL_S)

    def _demand(self, study: optuna.Study) -> Demand:
        """What the queue asks of the fleet: the runs queued (any batch's: a worker takes
        the oldest), the jobs holding a running run, the runs finished so far."""
        trials = self.patience(lambda: study.get_trials(deepcopy=False))
        return Demand(
            waiting=sum(t.state == TrialState.WAITING for t in trials),
            holders=frozenset(
                str(t.system_attrs[JOB_ATTR])
                for t in trials
                if t.state == TrialState.RUNNING and JOB_ATTR in t.system_attrs
            ),
            finished=sum(t.state == TrialState.COMPLETE for t in trials),
        )


class _StaleJudge:
    """Fail stale trials and queue their copies, also copies a dead judge never queued.

    Optuna's check reads the running trials only, at every call; :func:`queue_lost_copies`
    reads every trial with its attributes — on PostgreSQL, with thousands of trials and
    many workers polling every ``POLL_S``, a query load for nothing — so it runs once a
    heartbeat interval: it acts only on failures older than three.
    """

    def __init__(self, patience: Patience, heartbeat_s: int) -> None:
        self.patience, self.heartbeat_s = patience, heartbeat_s
        self._scanned = -math.inf

    def __call__(self, study: optuna.Study) -> None:
        self.patience.stale_check(study)
        if time.monotonic() - self._scanned >= self.heartbeat_s:
            self.patience(lambda: queue_lost_copies(study, settled_s=3 * self.heartbeat_s))
            self._scanned = time.monotonic()


# -- working ---------------------------------------------------------------------------------
class _Interrupted(BaseException):
    """Raised in the main thread by SIGTERM while a solve runs."""


@one_blas_thread_within
def work(
    study: str | Path | StudySpec,
    *,
    storage: str,
    jobs: int = 1,
    heartbeat_s: int = HEARTBEAT_S,
    idle_timeout_s: float = 60.0,
    storage_patience_s: float = STORAGE_PATIENCE_S,
    storage_reached: bool = False,
    solve: Solve = solve_inputs,
    progress: bool = True,
    max_runs: int | None = None,
    queue: str = "verify",
) -> WorkerResult:
    """Run queued verification trials of ``study`` until none is left.

    Parameters
    ----------
    study : path or StudySpec
        The study file the plan was made from (same rig, solver and space).
    storage : str
        Storage URL of the plan (``postgresql://…``, ``journal:///….log``;
        ``sqlite:///…`` for one worker only).
    jobs : int
        Worker processes on this machine (1: this process).
    heartbeat_s : int
        Heartbeat interval [s]; a trial silent for three intervals is retried.
    idle_timeout_s : float
        Wait this long for new trials once the queue is empty and nothing runs.
    storage_patience_s : float
        Once connected, ride out a database that cannot be reached for this long
        (a restart, a failover) before stopping with a one-line error.
    storage_reached : bool
        The caller reached the storage before (the planner): the worker's start rides out
        an outage too. Otherwise a database it cannot reach at its start stops it at once.
        Its worker processes (``jobs`` > 1) start after this one reached it, and ride
        out an outage at their start either way.
    solve : callable
        The full solver on :func:`surrogate.identify._verify.verification_inputs`
        (tests pass a cheap stand-in here; a study file cannot).
    progress : bool
        One line per finished run (logger ``surrogate``, stderr unless configured).
    max_runs : int, optional
        Leave after this many runs (each worker process); then runs of other workers do
        not keep it waiting either (a scheduler's job: one run, ``--max-runs 1``).
    queue : str
        ``verify`` (the main job's verify study) or ``runs`` (the run queue of
        ``calibrate``/``diagnose --launcher``, :mod:`surrogate.identify._runs`).
    """
    spec = study if isinstance(study, StudySpec) else load_study(study)
    rules = queue_named(queue)
    rules.check(spec)
    check_jobs(jobs)
    check_workers(storage, jobs)
    if not isinstance(idle_timeout_s, int | float) or not idle_timeout_s >= 0:
        raise InputDataError(f"--idle-timeout must be ≥ 0 s, got {idle_timeout_s!r}")
    check_storage_patience(storage_patience_s)
    if max_runs is not None and (
        isinstance(max_runs, bool) or not isinstance(max_runs, int) or max_runs < 1
    ):
        raise InputDataError(f"--max-runs must be a whole number ≥ 1, got {max_runs!r}")
    quiet_optuna()
    if progress:
        show_progress()
    options: dict[str, Any] = {
        "heartbeat_s": heartbeat_s,
        "patience_s": storage_patience_s,
        "max_runs": max_runs,
        "queue": rules,
    }
    worker = _Worker(
        spec, storage, **options, reached=storage_reached, solve=solve, progress=progress
    )
    if jobs == 1:
        counts = worker.loop(idle_timeout_s)
    else:
        worker.close()
        options["reached"] = True  # by this process, just now
        counts = _work_in_processes(spec, storage, jobs, options, idle_timeout_s, solve, progress)
    return WorkerResult(rules.study_name(spec), storage, jobs, **counts)


def queue_named(name: str) -> Queue:
    """The rules of queue ``name`` (``verify``, ``runs``), or a one-line error."""
    from ._runs import RUNS

    queues: dict[str, Queue] = {VERIFY.name: VERIFY, RUNS.name: RUNS}
    if name not in queues:
        raise InputDataError(f"--queue must be one of {', '.join(queues)}, got {name!r}")
    return queues[name]


def _work_in_processes(
    spec: StudySpec,
    storage: str,
    jobs: int,
    options: dict[str, Any],
    idle_timeout_s: float,
    solve: Solve,
    progress: bool,
) -> dict[str, Any]:
    """``jobs`` worker processes; SIGTERM to this one is passed on to them."""
    # the package's one start method (surrogate._pool); a child lets go of the database
    # connections it inherits (surrogate.storage) and opens its own storage
    context = process_context()
    results = context.SimpleQueue()
    processes = [
        context.Process(
            target=_process_main,
            args=(results, spec, storage, options, idle_timeout_s, solve, progress),
        )
        for _ in range(jobs)
    ]
    for process in processes:
        process.start()

    received: list[str] = []  # the signals this process got, whatever its children did

    def forward(signum: int, frame: Any) -> None:
        received.append(signal.Signals(signum).name)
        for process in processes:
            if process.pid is not None and process.is_alive():
                process.terminate()

    previous = catch_signal(signal.SIGTERM, forward)  # ignored: as the children do
    try:
        for process in processes:
            while process.is_alive():
                process.join(timeout=0.5)
    except KeyboardInterrupt:  # the children got SIGINT too and clean up
        received.append("SIGINT")
        for process in processes:
            process.join()
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    counts: dict[str, Any] = {"runs": 0, "ok": 0, "failed": 0, "solved": 0, "interrupted": None}
    errors = []
    while not results.empty():
        child = results.get()
        if "error" in child:
            errors.append(child["error"])
            continue
        for name in ("runs", "ok", "failed", "solved"):
            counts[name] += child[name]
        counts["interrupted"] = counts["interrupted"] or child["interrupted"]
    if received:  # also where a child got it before or after its own handlers
        counts["interrupted"] = received[0]
    elif errors:  # one line, as this process would have said it
        raise errors[0]
    elif counts["interrupted"] is not None:  # a child alone was signalled
        counts["interrupted"] = f"a worker process was stopped by {counts['interrupted']}"
    elif any(p.exitcode not in (0, None) for p in processes):
        counts["interrupted"] = "a worker process died"
    return counts


def _process_main(
    results: Any,
    spec: StudySpec,
    storage: str,
    options: dict[str, Any],
    idle_timeout_s: float,
    solve: Solve,
    progress: bool,
) -> None:
    one_blas_thread()
    quiet_optuna()
    try:
        worker = _Worker(spec, storage, **options, solve=solve, progress=progress)
        results.put(worker.loop(idle_timeout_s))
    except SurrogateError as error:  # the parent raises it: one line, not a child's traceback
        results.put({"error": error})
    except KeyboardInterrupt:  # Ctrl-C before the worker's handlers: the parent says it
        pass


class _Worker:
    """One worker process: claim, heartbeat, solve (through the cache), tell."""

    def __init__(
        self,
        spec: StudySpec,
        storage: str,
        *,
        heartbeat_s: int,
        patience_s: float,
        reached: bool = False,
        solve: Solve,
        progress: bool,
        max_runs: int | None = None,
        queue: Queue = VERIFY,
    ) -> None:
        self.url = storage
        self.max_runs = max_runs
        self.queue = queue
        self.job_id = os.environ.get(JOB_ID_VARIABLE) or None
        self._stop: str | None = None
        self.patience = Patience(
            storage, patience_s, grace_s=3 * heartbeat_s, stopping=lambda: self._stop is not None
        )

        def start() -> tuple[Any, optuna.Study, int]:
            # get_storage: the study and this worker share one (cached) storage object
            opened: Any = optuna.storages.get_storage(
                open_storage(storage, heartbeat_s=heartbeat_s, must_exist=True)
            )
            name = queue.study_name(spec)
            try:
                study = optuna.load_study(
                    study_name=name, storage=opened, sampler=optuna.samplers.RandomSampler()
                )
            except KeyError:
                raise InputDataError(queue.missing(spec, storage)) from None
            return opened, study, opened.get_study_id_from_name(name)

        with storage_errors(storage):  # a database never reached is not waited for
            self.storage, self.study, self.study_id = self.patience(start) if reached else start()
        self.spec = queue.planned(spec, self.study.user_attrs)
        self.heartbeat_s = heartbeat_s
        self.solve = solve
        self.progress = progress
        self.cache = ResultCache(spec.directory / ".solver-cache")
        self.counts: dict[str, Any] = {
            "runs": 0,
            "ok": 0,
            "failed": 0,
            "solved": 0,
            "interrupted": None,
        }
        self._solving = False
        self._listening = False  # a SIGTERM or SIGINT handler of this loop is installed

    def close(self) -> None:
        engine = getattr(getattr(self.storage, "_backend", self.storage), "engine", None)
        if engine is not None:
            engine.dispose()

    def loop(self, idle_timeout_s: float) -> dict[str, Any]:
        """Work until nothing has been queued or running for ``idle_timeout_s`` (with
        ``max_runs``: until that many runs, or nothing queued for ``idle_timeout_s``).

        SIGTERM and SIGINT stop it between runs, or give the running one back; one the
        process ignores stays ignored (:func:`~surrogate._pool.catch_signal`)."""
        main_thread = threading.current_thread() is threading.main_thread()
        caught = {sig: catch_signal(sig, self._on_signal) for sig in _SIGNALS if main_thread}
        previous = {sig: handler for sig, handler in caught.items() if handler is not None}
        self._listening = bool(previous)
        try:
            with storage_errors(self.url):
                idle_since = time.monotonic()
                judge = _StaleJudge(self.patience, self.heartbeat_s)
                taken = 0
                while self._stop is None and taken != self.max_runs:
                    judge(self.study)
                    trial_id = self._claim()
                    if trial_id is not None:
                        self._run(trial_id)
                        taken += 1
                        idle_since = time.monotonic()
                    elif self.max_runs is None and self.patience(self._running):
                        # idle once nothing is queued or running
                        idle_since = time.monotonic()
                        time.sleep(POLL_S)
                    elif time.monotonic() - idle_since < idle_timeout_s:
                        time.sleep(POLL_S)
                    else:
                        break
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            self.close()
        self.counts["interrupted"] = self._stop
        return dict(self.counts)

    def _on_signal(self, signum: int, frame: Any) -> None:
        self._stop = signal.Signals(signum).name
        if self._solving:
            raise _Interrupted(self._stop)

    def _claim(self) -> int | None:
        """Move one WAITING trial to RUNNING for this worker (the storage arbitrates).

        A claim retried after its answer was lost finds the trial RUNNING and moves on;
        that trial, never beating, goes stale and is queued again."""
        waiting = self.patience(
            lambda: self.storage.get_all_trials(
                self.study_id, deepcopy=False, states=(TrialState.WAITING,)
            )
        )
        for trial in waiting:
            trial_id = trial._trial_id
            try:
                claim = partial(self.storage.set_trial_state_values, trial_id, TrialState.RUNNING)
                if self.patience(claim):
                    self.patience(partial(self.storage.record_heartbeat, trial_id))
                    if self.job_id is not None:  # the planner's fleet: this job holds a run
                        self.patience(
                            partial(
                                self.storage.set_trial_system_attr, trial_id, JOB_ATTR, self.job_id
                            )
                        )
                    return trial_id
            except optuna.exceptions.UpdateFinishedTrialError:
                continue
        return None

    def _running(self) -> bool:
        return bool(
            self.storage.get_all_trials(self.study_id, deepcopy=False, states=(TrialState.RUNNING,))
        )

    def _run(self, trial_id: int) -> None:
        trial = optuna.Trial(self.study, trial_id)
        beat = _HeartbeatThread(self.storage, trial_id, self.heartbeat_s, self.patience)
        beat.start()
        try:
            params, inputs = self.patience(lambda: self.queue.inputs(self.spec, trial))
            key = input_hash(inputs)
            queued = trial.user_attrs.get("input_hash", key)
            # another solver version or settings than the planner's: refuse rather than
            # solve something else (the trial keeps the planner's hash, so it waits no more)
            result = self._result(key, inputs) if queued == key else _OTHER_INPUTS
        except _Interrupted:
            beat.stop()
            self._requeue(trial)
            return
        except optuna.exceptions.UpdateFinishedTrialError:
            beat.stop()
            self._judged_stale(trial)
            return
        except BaseException:
            beat.stop()
            raise
        beat.stop()

        def tell() -> Any:
            trial.set_user_attr("input_hash", queued)
            return self.queue.tell(self.study, trial, self.spec, params, result)

        try:
            record = self.patience(tell)
        except (optuna.exceptions.UpdateFinishedTrialError, ValueError):
            # finished meanwhile: failed as stale, or by this tell whose answer was lost
            frozen = self.patience(partial(self.storage.get_trial, trial_id))
            if frozen.state == TrialState.RUNNING:
                raise
            if frozen.state == TrialState.COMPLETE or "reason" in frozen.user_attrs:
                self._count(trial.number, self.queue.record_of(frozen))
            else:
                self._judged_stale(trial)
            return
        self._count(trial.number, record)

    def _judged_stale(self, trial: optuna.Trial) -> None:
        """Another worker failed this live trial as stale (its heartbeats could not be
        written in time) and queued a copy, which takes the cached result if there is one."""
        if self.progress:
            logger.info(
                "[%s] trial %d: judged stale by another worker while running; "
                "its queued copy takes the result",
                self.spec.name,
                trial.number,
            )

    def _result(self, key: str, inputs: dict[str, Any]) -> dict[str, Any]:
        result = self.cache.get(key)
        if result is not None:
            return result
        if self._stop is not None:
            raise _Interrupted(self._stop)
        self._solving = True
        try:
            result = self.solve(inputs)
        except KeyboardInterrupt:
            self._stop = "SIGINT"
            raise _Interrupted(self._stop) from None
        except Exception as error:  # a broken solver fails this run, not the worker
            result = {"status": "failed", "reason": f"{type(error).__name__}: {error}"}
        finally:
            self._solving = False
        if result.get("status") != "ok" and self._stopped_within(STOP_GRACE_S):
            raise _Interrupted(self._stop)  # killed by the stop: given back, not cached
        self.counts["solved"] += 1
        self.cache.put(key, inputs, result)
        return result

    def _stopped_within(self, seconds: float) -> bool:
        """Whether a stop signal has come, or comes within ``seconds`` (its handler runs
        in this, the main, thread between the sleeps; with no handler installed, none
        can come: no wait)."""
        deadline = time.monotonic() + seconds
        while self._listening and self._stop is None and time.monotonic() < deadline:
            time.sleep(0.05)
        return self._stop is not None

    def _requeue(self, trial: optuna.Trial) -> None:
        """FAIL the interrupted trial after queueing its copy (as a stale trial's)."""
        frozen = self.storage.get_trial(trial._trial_id)
        retry_callback()(self.study, frozen)
        try:
            self.storage.set_trial_system_attr(trial._trial_id, "interrupted", self._stop)
            self.study.tell(trial, state=TrialState.FAIL)
        except optuna.exceptions.UpdateFinishedTrialError:
            pass  # judged stale meanwhile: failed and queued again already
        if self.progress:
            logger.info(
                "[%s] trial %d: stopped by %s; queued again for another worker",
                self.spec.name,
                trial.number,
                self._stop,
            )

    def _count(self, number: int, record: Any) -> None:
        self.counts["runs"] += 1
        self.counts["ok" if record.ok else "failed"] += 1
        if self.progress:
            logger.info("[%s] trial %d: %s", self.spec.name, number, self.queue.describe(record))


_SIGNALS = (signal.SIGTERM, signal.SIGINT)
_SIGNAL_NAMES = {signal.Signals(number).name for number in _SIGNALS}
_OTHER_INPUTS = {
    "status": "failed",
    "reason": "this worker's solver inputs differ from the planner's (another solver "
    "version or [solver] settings); start workers with the planner's study file and solver",
}


class _HeartbeatThread:
    """Records the trial's heartbeat every ``interval_s`` until stopped."""

    def __init__(self, storage: Any, trial_id: int, interval_s: int, patience: Patience) -> None:
        self._storage = storage
        self._trial_id = trial_id
        self._interval_s = interval_s
        self._patience = patience
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopped.set()
        self._thread.join()

    def _beat(self) -> None:
        while not self._stopped.wait(self._interval_s):
            try:
                self._storage.record_heartbeat(self._trial_id)
            except optuna.exceptions.UpdateFinishedTrialError:
                return  # failed as stale by another worker: nothing to keep alive
            except Exception as error:  # a storage hiccup: the next beat retries
                if unreachable(error):
                    self._patience.failed()  # judge no one stale until it is over
                continue
