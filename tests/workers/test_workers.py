"""Many workers on one storage: every run exactly once, faults cost one run at most.

Workers are real processes (``python -m tests.workers.fixed_cost``) running
``surrogate.identify._worker.work`` with the fixed-cost stand-in solver, on the journal
file and on a throwaway PostgreSQL server.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest

from surrogate._errors import SolverError
from surrogate.identify._doe import make_design
from surrogate.identify._verify import enqueue, open_verify_study
from surrogate.identify._worker import WorkerDispatcher, work
from surrogate.storage._storage import MAX_RETRY, open_storage
from surrogate.study._spec import load_study
from tests.test_journal_lock import die_inside_the_lock
from tests.workers.fixed_cost import FixedCostSolve, events

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow
TrialState = optuna.trial.TrialState


def _plan(study_file, storage_url, n):
    spec = load_study(study_file)
    study = open_verify_study(spec, storage_url, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=n, seed=3).to_dict("records")
    return enqueue(study, spec, points, phase="plan")


def _process(*args, preexec_fn=None):
    """``python -m ARGS…`` from the repository, its output captured."""
    return subprocess.Popen(
        [sys.executable, "-m", *map(str, args)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=preexec_fn,
    )


def _worker(study_file, storage_url, log, cost_s, *, jobs=1, options=()):
    """A worker process with the fixed-cost solver (``tests/workers/fixed_cost.py``)."""
    return _process(
        "tests.workers.fixed_cost", study_file, storage_url, log, cost_s, jobs, *options
    )


def _trials(study_file, storage_url):
    spec = load_study(study_file)
    study = optuna.load_study(study_name=f"{spec.name}/verify", storage=open_storage(storage_url))
    return study.get_trials(deepcopy=False)


def _wait_all(processes, timeout=120):
    for process in processes:
        _, stderr = process.communicate(timeout=timeout)
        assert process.returncode == 0, stderr


def _wait_for(condition, timeout=60, every=0.05):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(every)
    raise AssertionError("timed out")


def _claim_one(study_file, storage_url):
    """The storage (1 s heartbeat) and the first queued trial, claimed as a worker would."""
    spec = load_study(study_file)
    storage = open_storage(storage_url, heartbeat_s=1)
    study = optuna.load_study(study_name=f"{spec.name}/verify", storage=storage)
    trial = study.get_trials(deepcopy=False, states=(TrialState.WAITING,))[0]
    assert storage.set_trial_state_values(trial._trial_id, state=TrialState.RUNNING)
    return storage, trial


def _work_here(study, storage_url, log, idle_timeout_s=0.0):
    """A worker in this process (1 s heartbeat) until nothing is queued or running."""
    return work(
        study,
        storage=storage_url,
        heartbeat_s=1,
        idle_timeout_s=idle_timeout_s,
        solve=FixedCostSolve(log, 0.0),
        progress=False,
    )


def test_four_workers_finish_a_40_run_plan_each_run_exactly_once(study_file, storage_url, tmp_path):
    keys = _plan(study_file, storage_url, 40)
    assert len(set(keys)) == 40
    log = tmp_path / "solver.log"
    _wait_all([_worker(study_file, storage_url, log, 0.15) for _ in range(4)])
    trials = _trials(study_file, storage_url)
    assert len(trials) == 40 and all(t.state == TrialState.COMPLETE for t in trials)
    assert sorted(t.user_attrs["input_hash"] for t in trials) == sorted(keys)
    log_events = events(log)
    assert collections.Counter((e, k) for e, k, _ in log_events) == {
        **{("start", k): 1 for k in keys},
        **{("done", k): 1 for k in keys},
    }
    # the runs really were shared: more than one process solved
    assert len({pid for _, _, pid in log_events}) >= 2


def test_jobs_spawns_local_worker_processes(study_file, tmp_path):
    storage_url = f"journal://{tmp_path / 'study.log'}"
    keys = _plan(study_file, storage_url, 8)
    log = tmp_path / "solver.log"
    _wait_all([_worker(study_file, storage_url, log, 0.3, jobs=2)])
    assert sorted(k for e, k, _ in events(log) if e == "done") == sorted(keys)
    assert len({pid for _, _, pid in events(log)}) == 2


def test_sigkilled_worker_costs_one_run_redone_once(study_file, storage_url, tmp_path):
    keys = _plan(study_file, storage_url, 9)
    log = tmp_path / "solver.log"
    victim = _worker(study_file, storage_url, log, 2.0)
    started = _wait_for(lambda: [k for e, k, pid in events(log) if pid == victim.pid])
    others = [_worker(study_file, storage_url, log, 0.3) for _ in range(2)]
    victim.send_signal(signal.SIGKILL)  # mid-solve: the run takes 2 s
    victim.wait(timeout=10)
    _wait_all(others)
    killed = started[0]
    trials = _trials(study_file, storage_url)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert sorted(t.user_attrs["input_hash"] for t in complete) == sorted(keys)
    failed = [t for t in trials if t.state == TrialState.FAIL]
    assert [t.user_attrs["input_hash"] for t in failed] == [killed]
    retry = next(t for t in complete if t.user_attrs["input_hash"] == killed)
    assert retry.system_attrs["failed_trial"] == failed[0].number
    starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
    dones = collections.Counter(k for e, k, _ in events(log) if e == "done")
    assert starts == {k: 2 if k == killed else 1 for k in keys}
    assert dones == dict.fromkeys(keys, 1)


def test_a_writer_killed_inside_the_journal_lock_makes_no_live_trial_stale(study_file, tmp_path):
    """A killed writer's symlink lock, left where the workers' heartbeats must pass: with
    Optuna's lock alone they stood still for its 30 s grace, and a live trial was failed
    as stale and run again (surrogate.storage._lock)."""
    journal = tmp_path / "study.log"
    storage_url = f"journal://{journal}"
    keys = _plan(study_file, storage_url, 6)
    log = tmp_path / "solver.log"
    workers = [_worker(study_file, storage_url, log, 2.0) for _ in range(2)]  # 1 s heartbeat
    _wait_for(lambda: len([e for e, _, _ in events(log) if e == "start"]) >= 2)
    die_inside_the_lock(str(journal))  # a writer SIGKILLed while it appends
    _wait_all(workers)
    trials = _trials(study_file, storage_url)
    assert [t.state for t in trials] == [TrialState.COMPLETE] * len(keys)
    starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
    assert starts == dict.fromkeys(keys, 1)


def test_a_worker_whose_live_trial_is_judged_stale_goes_on_and_repeats_no_run(study_file, tmp_path):
    """Another worker fails a live trial as stale (its heartbeats were not written in
    time: a lock a killed writer left, an unreachable database) and queues a copy, as
    ``optuna.storages.fail_stale_trials`` does. The worker that ran it goes on (it
    stopped with UpdateFinishedTrialError before), and the copy takes the cached result."""
    storage_url = f"journal://{tmp_path / 'study.log'}"
    keys = _plan(study_file, storage_url, 3)
    spec = load_study(study_file)
    storage = open_storage(storage_url)
    study = optuna.load_study(study_name=f"{spec.name}/verify", storage=storage)
    log = tmp_path / "solver.log"
    fixed = FixedCostSolve(log, 0.0)
    judged: list[int] = []

    def solve(inputs):
        if not judged:
            (running,) = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
            assert storage.set_trial_state_values(running._trial_id, state=TrialState.FAIL)
            optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=MAX_RETRY)(
                study, storage.get_trial(running._trial_id)
            )
            judged.append(running.number)
        return fixed(inputs)

    result = work(study_file, storage=storage_url, idle_timeout_s=0.0, solve=solve, progress=False)
    trials = _trials(study_file, storage_url)
    assert [t.number for t in trials if t.state == TrialState.FAIL] == judged
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert sorted(t.user_attrs["input_hash"] for t in complete) == sorted(keys)
    starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
    assert starts == dict.fromkeys(keys, 1)
    assert result.runs == len(keys)


def test_a_trial_failed_as_stale_whose_copy_was_never_queued_gets_one(study_file, tmp_path):
    """``fail_stale_trials`` fails a stale trial, then queues its copy: a judge killed or cut
    off from the storage in between left a FAIL trial whose copy the planner awaited for
    ever. Once the FAIL is older than the grace, the next worker queues the copy."""
    storage_url = f"journal://{tmp_path / 'study.log'}"
    keys = _plan(study_file, storage_url, 3)
    storage, judged = _claim_one(study_file, storage_url)
    assert storage.set_trial_state_values(judged._trial_id, state=TrialState.FAIL)
    time.sleep(3.5)  # past the grace: three heartbeat intervals
    log = tmp_path / "solver.log"
    result = _work_here(study_file, storage_url, log)
    trials = _trials(study_file, storage_url)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert sorted(t.user_attrs["input_hash"] for t in complete) == sorted(keys)
    (copy,) = [t for t in complete if judged.number in t.system_attrs.get("retry_history", [])]
    assert copy.user_attrs["input_hash"] == judged.user_attrs["input_hash"]
    assert result.runs == len(keys)


def test_a_worker_scans_for_lost_copies_once_a_heartbeat_interval(
    study_file, tmp_path, monkeypatch
):
    """The scan for lost copies reads every trial with its attributes: once a heartbeat
    interval, not at every poll (``POLL_S``, 0.5 s while idle: twice as often with the
    1 s heartbeat here) — it acts only on failures older than three intervals."""
    from surrogate.identify import _worker

    scans = []
    scan = _worker.queue_lost_copies
    monkeypatch.setattr(
        _worker,
        "queue_lost_copies",
        lambda *a, **k: (scans.append(time.monotonic()), scan(*a, **k)),
    )
    storage_url = f"journal://{tmp_path / 'study.log'}"
    _plan(study_file, storage_url, 1)
    start = time.monotonic()
    _work_here(study_file, storage_url, tmp_path / "solver.log", idle_timeout_s=3.0)
    elapsed = time.monotonic() - start
    assert elapsed >= 3.0 and 3 <= len(scans) <= elapsed / 1.0 + 1, (elapsed, scans)
    assert min(b - a for a, b in itertools.pairwise(scans)) >= 1.0


def test_sigterm_fails_the_trial_and_another_worker_redoes_it(study_file, storage_url, tmp_path):
    keys = _plan(study_file, storage_url, 3)
    log = tmp_path / "solver.log"
    first = _worker(study_file, storage_url, log, 3.0)
    started = _wait_for(lambda: [k for e, k, _ in events(log) if e == "start"])
    first.send_signal(signal.SIGTERM)
    _, stderr = first.communicate(timeout=30)
    assert first.returncode == 143, stderr
    trials = _trials(study_file, storage_url)
    failed = [t for t in trials if t.state == TrialState.FAIL]
    assert [(t.user_attrs["input_hash"], t.system_attrs["interrupted"]) for t in failed] == [
        (started[0], "SIGTERM")
    ]
    queued = [t for t in trials if t.state == TrialState.WAITING]
    assert started[0] in {t.user_attrs["input_hash"] for t in queued}
    assert not [t for t in trials if t.state == TrialState.RUNNING]
    _wait_all([_worker(study_file, storage_url, log, 0.1)])
    trials = _trials(study_file, storage_url)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert sorted(t.user_attrs["input_hash"] for t in complete) == sorted(keys)
    dones = collections.Counter(k for e, k, _ in events(log) if e == "done")
    assert dones == dict.fromkeys(keys, 1)


def test_a_solve_that_fails_of_the_workers_stop_gives_its_run_back(
    study_file, storage_url, tmp_path
):
    """A job cancelled by the scheduler: its solver's program dies of the SIGTERM and fails
    before the worker's own SIGTERM comes (here 0.1 s later). That failure is the cancel's:
    the run is given back (queued again, nothing recorded or cached as its result), and
    another worker solves it (the code before recorded the run failed, and a planner
    restarted then never solved it)."""
    [key] = _plan(study_file, storage_url, 1)
    log = tmp_path / "solver.log"
    cancelled = _worker(study_file, storage_url, log, 0.0, options=("--cancelled",))
    _, stderr = cancelled.communicate(timeout=60)
    assert cancelled.returncode == 143, stderr
    trials = _trials(study_file, storage_url)
    assert not [t for t in trials if "reason" in t.user_attrs]  # no failure recorded
    assert [t.system_attrs.get("interrupted") for t in trials if t.state == TrialState.FAIL] == [
        "SIGTERM"
    ]
    assert [t.user_attrs["input_hash"] for t in trials if t.state == TrialState.WAITING] == [key]
    _wait_all([_worker(study_file, storage_url, log, 0.0)])
    complete = [t for t in _trials(study_file, storage_url) if t.state == TrialState.COMPLETE]
    assert [t.user_attrs["input_hash"] for t in complete] == [key]  # solved, not a cached failure
    assert [k for e, k, _ in events(log) if e == "done"] == [key]


def test_a_planner_stopped_by_sigterm_while_its_workers_solve_stops_and_resumes(
    study_file, tmp_path
):
    """``surrogate run --jobs 2`` passes SIGTERM to its worker processes, which give their
    runs back; the planner then stops with 143 and one line. Before, it went on waiting
    for the runs given back, which nothing would run (it hung until SIGKILL). The same
    command resumes: every run of the plan is finished once."""
    storage_url = f"journal://{tmp_path / 'study.log'}"
    log = tmp_path / "solver.log"
    args = [study_file, "--storage", storage_url, "--jobs", 2, "--budget", 6, "--json"]
    planner = _process("tests.workers.fixed_cost_planner", log, 60.0, *args)

    def solving():  # both worker processes
        return len([e for e, _, _ in events(log) if e == "start"]) >= 2

    stderr = _signalled(planner, signal.SIGTERM, once=solving)  # the code before hung here
    assert planner.returncode == 143, stderr
    last = stderr.strip().splitlines()[-1]
    assert "stopped by SIGTERM" in last and "the same command resumes" in last, stderr
    trials = _trials(study_file, storage_url)
    assert not [t for t in trials if t.state == TrialState.RUNNING]
    given_back = [t for t in trials if t.system_attrs.get("interrupted") == "SIGTERM"]
    assert len(given_back) == 2
    queued = {t.user_attrs["input_hash"] for t in trials if t.state == TrialState.WAITING}
    assert {t.user_attrs["input_hash"] for t in given_back} <= queued

    again = _process("tests.workers.fixed_cost_planner", log, 0.0, *args)
    stdout, stderr = again.communicate(timeout=120)
    assert again.returncode == 0, stderr
    assert json.loads(stdout)["solver_calls"] == 6
    trials = _trials(study_file, storage_url)
    finished = collections.Counter(
        t.user_attrs["input_hash"] for t in trials if t.state == TrialState.COMPLETE
    )
    assert len(finished) == 6 and set(finished.values()) == {1}
    dones = collections.Counter(k for e, k, _ in events(log) if e == "done")
    assert dones == finished


def test_a_planners_worker_processes_that_die_have_their_runs_redone(study_file, tmp_path):
    """``run --jobs 2``: both local worker processes die mid-solve; the planner starts
    its workers again, which find the runs stale and redo them. Before, the planner
    waited for ever for the copies, which nothing would run."""
    batch = _batch_with_dying_workers(study_file, tmp_path, deaths=2)
    with _alarm(120, "the planner still waits for the dead worker's run"):
        found = batch()
    log = tmp_path / "solver.log"
    assert (tmp_path / "death-1").exists()
    assert len(found) == 4 and all(record.ok for record in found.values())
    starts = collections.Counter(k for e, k, _ in events(log) if e == "start")
    dones = collections.Counter(k for e, k, _ in events(log) if e == "done")
    assert dones == dict.fromkeys(found, 1)
    assert sorted(starts.values()) == [1, 1, 2, 2]  # the dead workers' runs, redone once


def test_a_planners_worker_processes_that_die_every_round_stop_it_with_one_line(
    study_file, tmp_path
):
    """Local workers whose every solve kills them: after ``MAX_RETRY + 1`` rounds the
    planner stops, saying what is open and what to do, instead of waiting for ever for
    runs nothing here will run. (A round's workers may leave without a solve while a
    dead run is failed and its copy not yet queued, so how many die is not fixed; the
    first two rounds each find two runs queued, and no run ever finishes.)"""
    batch = _batch_with_dying_workers(study_file, tmp_path, deaths=100)
    with (
        _alarm(120, "the planner still waits for the dead workers' runs"),
        pytest.raises(SolverError, match=r"runs still open after 4 rounds of local worker"),
    ):
        batch()
    assert (tmp_path / "death-3").exists()
    assert not [e for e, _, _ in events(tmp_path / "solver.log") if e == "done"]


def _trials_recorded(storage: Path) -> int:
    """Trials in a SQLite Optuna storage, 0 before its tables exist (read-only)."""
    import sqlite3

    if not storage.exists():
        return 0
    try:
        with contextlib.closing(sqlite3.connect(f"file:{storage}?mode=ro", uri=True)) as db:
            return int(db.execute("SELECT count(*) FROM trials").fetchone()[0])
    except sqlite3.Error:
        return 0


def _as_a_terminals_job():
    """``preexec_fn``: SIGINT at its default, as in a terminal's foreground job. A suite
    started as a shell script's background job (``pytest … &``) runs with SIGINT ignored,
    and every process it starts inherits that: the three fresh-clone runs that failed
    the Ctrl-C test had been started so."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_a_run_with_one_line(study_file, tmp_path):
    """SIGINT (Ctrl-C) while the planner works — its initial design queued: exit 130 and
    one line, no traceback. The same run is done once before, so numba's kernels are
    compiled and cached (a Ctrl-C in its compiler crashed it once in 40 tries)."""
    warm = _process("surrogate", "run", study_file, "--storage", f"sqlite:///{tmp_path / 'w.db'}")
    warm.communicate(timeout=300)
    assert warm.returncode == 0
    storage = tmp_path / "run.db"
    planner = _process(
        "surrogate",
        "run",
        study_file,
        "--storage",
        f"sqlite:///{storage}",
        preexec_fn=_as_a_terminals_job,
    )
    stderr = _signalled(planner, signal.SIGINT, once=lambda: _trials_recorded(storage) > 0)
    assert planner.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "surrogate: interrupted (Ctrl-C)", stderr
    assert "Traceback" not in stderr


_INTERRUPTED_QUERY = """
import logging, sqlite3, sys
import sqlalchemy
from surrogate._cli import main

class Interrupted(sqlite3.Cursor):
    def fetchall(self):
        raise KeyboardInterrupt  # the SIGINT, inside the database's fetch

class Connection(sqlite3.Connection):
    def cursor(self, factory=Interrupted):
        return super().cursor(factory)

if sys.argv[1:] == ["cli"]:  # a command ran first in this process: its logging stays
    main(["simulate", "--ecoat", "1", "--scoat", "0.2", "--tcoat", "0.012"])
engine = sqlalchemy.create_engine(
    "sqlite://", creator=lambda: sqlite3.connect(":memory:", factory=Connection)
)
try:
    with engine.connect() as connection:
        result = connection.execute(sqlalchemy.text("SELECT 1"))
        try:
            result.fetchall()
        finally:
            result.close()
except KeyboardInterrupt:
    print("surrogate: interrupted (Ctrl-C)", file=sys.stderr)
logging.getLogger("sqlalchemy.pool").error("another error of SQLAlchemy's")
logging.getLogger("sqlalchemy.engine").setLevel(logging.INFO)
logging.getLogger("sqlalchemy.engine").info("a statement: below the last resort's WARNING")
"""


def test_a_ctrl_c_inside_a_query_is_not_echoed_by_sqlalchemy():
    """A real SQLAlchemy engine whose cursor raises KeyboardInterrupt in its fetch logs "Error
    closing cursor" with two tracebacks (the Ctrl-C test above failed so once, with three
    pytest processes on two cores); after a command's ``main`` only the command's line and
    SQLAlchemy's other records reach stderr (:func:`surrogate._log.drop_ctrl_c_echoes`)."""

    def stderr(*args):
        done = subprocess.run(
            [sys.executable, "-c", _INTERRUPTED_QUERY, *args],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        return done.stderr

    bare = stderr()
    assert "Error closing cursor" in bare and "Cannot operate on a closed database" in bare
    assert stderr("cli") == ("surrogate: interrupted (Ctrl-C)\nanother error of SQLAlchemy's\n")


def test_a_worker_started_ignoring_sigint_ignores_it(study_file, tmp_path):
    """A process started with SIGINT ignored (a shell script's background job: a Ctrl-C
    there is meant for the script's foreground) keeps it ignored in its worker loop too:
    every queued run is done through a SIGINT inside each solve. Before, the loop caught
    it while the rest of the command ignored it, so ``surrogate run`` started that way
    stopped at the Ctrl-Cs that came while it solved and ran on through the others."""
    storage_url = f"journal://{tmp_path / 'study.log'}"
    keys = _plan(study_file, storage_url, 3)
    fixed = FixedCostSolve(tmp_path / "solver.log", 0.0)

    def solve(inputs):
        os.kill(os.getpid(), signal.SIGINT)
        return fixed(inputs)

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        result = work(
            study_file, storage=storage_url, idle_timeout_s=0.0, solve=solve, progress=False
        )
    finally:
        signal.signal(signal.SIGINT, previous)
    assert result.interrupted is None and result.ok == len(keys), result


def _batch_with_dying_workers(study_file, tmp_path, *, deaths):
    """A planner's batch of 4 runs on 2 local worker processes whose first ``deaths``
    solves kill their process (fixed-cost stand-in, 0.2 s, log ``solver.log``)."""
    storage_url = f"journal://{tmp_path / 'study.log'}"
    spec = load_study(study_file)
    study = open_verify_study(spec, storage_url, heartbeat_s=1)
    solve = FixedCostSolve(tmp_path / "solver.log", 0.2, deaths=(tmp_path, deaths))
    dispatcher = WorkerDispatcher(
        spec, storage_url, jobs=2, heartbeat_s=1, solve=solve, progress=False
    )
    points = make_design("lhs", spec.space, n=4, seed=3).to_dict("records")
    return lambda: dispatcher(study, points, "plan")


def _signalled(process, signum, *, once):
    """``process``'s stderr, sent ``signum`` once ``once()`` holds; killed if it has not
    ended 60 s later (nothing is left running when the test fails)."""
    try:
        _wait_for(once, timeout=60)
        process.send_signal(signum)
        return process.communicate(timeout=60)[1]
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=30)


@contextlib.contextmanager
def _alarm(seconds, message):
    """``TimeoutError(message)`` in this (the main) thread if the block takes longer."""

    def ring(signum, frame):
        raise TimeoutError(message)

    previous = signal.signal(signal.SIGALRM, ring)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_a_solver_failure_is_a_fail_trial_with_its_reason_and_the_loop_goes_on(
    study_file, tmp_path
):
    storage_url = f"journal://{tmp_path / 'study.log'}"
    keys = _plan(study_file, storage_url, 6)
    solve = FixedCostSolve(tmp_path / "solver.log", 0.0, fail_above_tcoat_mm=0.03)
    result = work(study_file, storage=storage_url, idle_timeout_s=0.0, solve=solve, progress=False)
    trials = _trials(study_file, storage_url)
    failed = [t for t in trials if t.state == TrialState.FAIL]
    assert failed and len(failed) < len(keys)
    assert all(t.params["tcoat_mm"] > 0.03 for t in failed)
    assert all("stand-in solver refuses Tcoat" in t.user_attrs["reason"] for t in failed)
    assert result.runs == len(keys) and result.failed == len(failed)
    assert all(t.state == TrialState.COMPLETE for t in trials if t.params["tcoat_mm"] <= 0.03)
    assert os.path.exists(tmp_path / ".solver-cache")


def test_a_trial_claimed_without_a_first_heartbeat_is_failed_and_redone(
    study_file, storage_url, tmp_path
):
    """The window between a claim and its first heartbeat (two transactions), made
    deterministic: a worker 'dies' right after moving a trial to RUNNING."""
    keys = _plan(study_file, storage_url, 2)
    _, claimed = _claim_one(study_file, storage_url)
    time.sleep(3.5)  # past the grace period: three heartbeat intervals

    log = tmp_path / "solver.log"
    result = _work_here(study_file, storage_url, log)

    trials = _trials(study_file, storage_url)
    assert not [t for t in trials if t.state in (TrialState.RUNNING, TrialState.WAITING)]
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert sorted(t.user_attrs["input_hash"] for t in complete) == sorted(keys)
    failed = [t for t in trials if t.state == TrialState.FAIL]
    assert [t.number for t in failed] == [claimed.number]
    assert result.runs == 2 and result.solved == 2


def test_the_idle_timeout_counts_from_when_nothing_is_queued_or_running(study_file, tmp_path):
    """A worker waits out another worker's long run and then its idle timeout, so it
    is still there when the planner queues the next batch after that run."""
    import threading

    storage_url = f"journal://{tmp_path / 'study.log'}"
    _plan(study_file, storage_url, 1)
    spec = load_study(study_file)
    storage = open_storage(storage_url, heartbeat_s=1)
    study = optuna.load_study(study_name=f"{spec.name}/verify", storage=storage)
    other = study.get_trials(deepcopy=False, states=(TrialState.WAITING,))[0]
    storage.set_trial_state_values(other._trial_id, state=TrialState.RUNNING)  # another worker's

    log = tmp_path / "solver.log"
    results = []
    worker = threading.Thread(
        target=lambda: results.append(_work_here(spec, storage_url, log, idle_timeout_s=3.0))
    )
    worker.start()
    for _ in range(10):  # the other run takes 5 s (its worker keeps the heartbeat)
        storage.record_heartbeat(other._trial_id)
        time.sleep(0.5)
    storage.set_trial_state_values(other._trial_id, state=TrialState.COMPLETE, values=[0.0])
    time.sleep(1.5)  # the planner looks at the results and queues its next point
    points = make_design("lhs", spec.space, n=2, seed=11).to_dict("records")[1:]
    (key,) = enqueue(
        open_verify_study(spec, storage_url, heartbeat_s=None), spec, points, phase="b"
    )
    worker.join(timeout=30)

    assert not worker.is_alive() and results and results[0].runs == 1
    done = [t for t in _trials(study_file, storage_url) if t.user_attrs.get("input_hash") == key]
    assert [t.state for t in done] == [TrialState.COMPLETE]


def test_a_planner_that_waits_for_outside_workers_says_what_it_waits_for(
    study_file, tmp_path, caplog
):
    import logging
    import threading

    from surrogate.identify._worker import WorkerDispatcher

    storage_url = f"journal://{tmp_path / 'study.log'}"
    spec = load_study(study_file)
    study = open_verify_study(spec, storage_url, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=2, seed=5).to_dict("records")
    dispatch = WorkerDispatcher(spec, storage_url, jobs=0, heartbeat_s=1, progress=True)
    found = []
    with caplog.at_level(logging.INFO, logger="surrogate"):
        planner = threading.Thread(target=lambda: found.append(dispatch(study, points, "p")))
        planner.start()
        _wait_for(lambda: "waiting for 2 of 2 runs (2 queued, 0 running)" in caplog.text, 20)
        work(spec, storage=storage_url, idle_timeout_s=0.0, solve=FixedCostSolve(tmp_path / "l", 0))
        planner.join(timeout=20)
    assert "2 runs queued" in caplog.text and "waiting for `surrogate worker`" in caplog.text
    assert len(found) == 1 and all(r.ok for r in found[0].values())


def test_a_ctrl_c_python_swallowed_is_sent_again():
    """A KeyboardInterrupt raised where Python only prints "Exception ignored" (a weakref
    callback of the garbage collector, a ``__del__``, a ctypes callback of numba's
    compiler) was lost: ``surrogate run`` went on to exit 0 after 12 of 40 Ctrl-Cs sent
    0.4-1.2 s into it (25 exited 130, the rest with numba's SystemError or killed).
    The CLI's unraisable hook sends it again; anything else goes to the previous hook."""
    import types

    from surrogate import _cli

    got, seen = [], []

    def weakref_callback_raising(_):
        raise KeyboardInterrupt

    previous_handler = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    previous_hook = sys.unraisablehook
    _cli._UNRAISABLE_HOOK[0] = seen.append
    sys.unraisablehook = _cli._ctrl_c_again
    try:
        import weakref

        class Thing:
            pass

        thing = Thing()
        ref = weakref.ref(thing, weakref_callback_raising)  # noqa: F841 (kept: its callback runs)
        del thing  # the callback raises: unraisable, and handed to the hook
        _wait_for(lambda: got, timeout=5)
        assert got == [signal.SIGINT] and not seen
        other = types.SimpleNamespace(exc_value=ValueError("x"), exc_type=ValueError)
        _cli._ctrl_c_again(other)
        assert seen == [other] and got == [signal.SIGINT]
    finally:
        sys.unraisablehook = previous_hook
        _cli._UNRAISABLE_HOOK[0] = previous_hook
        signal.signal(signal.SIGINT, previous_handler)
