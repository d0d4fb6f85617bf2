"""The fault test an operator would run: four workers and a planner, killed mid-run.

A throwaway PostgreSQL on 127.0.0.1 (and the journal file), the planner
``surrogate run STUDY --jobs 0``, four worker processes with a solver slow enough
to kill mid-run (the fixed-cost stand-in, ``python -m tests.workers.fixed_cost``).
Then, in order:

1. the worker that started the first solve is SIGKILLed mid-solve;
2. a worker that stops dead between its claim and the claim's first heartbeat
   (the window made deterministic, ``--pause-at-first-heartbeat``) is SIGKILLed
   there — a trial RUNNING with no heartbeat at all;
3. each is replaced by a new worker;
4. once the planner has queued its first iteration, it is SIGKILLed and started
   again with the same command; it resumes the same plan.

From the storage afterwards: every planned input hash has exactly one finished
trial, none is RUNNING or WAITING, and the solver was started once per planned
point plus once per run killed mid-solve; the runs of each phase are those of
the same study run in one process and never killed. The figures are printed
(``-s``).
"""

from __future__ import annotations

import collections
import json
import shutil
import signal

import optuna
import pytest

from tests.workers.conftest import STUDIES
from tests.workers.fixed_cost import FixedCostSolve, events
from tests.workers.test_workers import _process, _trials, _wait_for
from tests.workers.test_workers import _worker as worker_process

pytestmark = pytest.mark.slow
TrialState = optuna.trial.TrialState
COST_S = 1.0
HEARTBEAT_S = 1


@pytest.fixture
def study_file(tmp_path):
    """The paper's study with batches of four (one run a worker) and a small budget."""
    text = (STUDIES / "paper_coating.toml").read_text()
    text = text.replace("initial_samples = 5", "initial_samples = 8")
    text = text.replace("candidates_per_iteration = 1", "candidates_per_iteration = 4")
    text = text.replace("max_solver_calls = 30", "max_solver_calls = 20")
    path = tmp_path / "paper_coating.toml"
    path.write_text(text)
    return path


def _planner(study_file, storage_url):
    return _process("surrogate", "run", study_file, "--storage", storage_url, "--jobs", 0, "--json")


def _worker(study_file, storage_url, log, *options):
    options = (HEARTBEAT_S, "--idle-timeout", 60, *options)
    return worker_process(study_file, storage_url, log, COST_S, options=options)


def _kill(process):
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)


def _first_start_by(log, workers):
    """The worker whose solve started first in the log, once one has."""
    pids = {process.pid: process for process in workers}
    for event, _, pid in events(log):
        if event == "start" and pid in pids:
            return pids[pid]
    return None


def test_killed_workers_and_planner_repeat_no_run_and_lose_none(study_file, storage_url, tmp_path):
    processes = []
    try:
        _the_fault_test(study_file, storage_url, tmp_path, processes)
    finally:  # a failed assertion leaves nothing running (a paused worker sleeps an hour)
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait(timeout=30)


def _the_fault_test(study_file, storage_url, tmp_path, processes):
    log = tmp_path / "solver.log"
    marker = tmp_path / "claimed"

    def start(process):
        processes.append(process)
        return process

    planner = start(_planner(study_file, storage_url))
    _wait_for(lambda: _has_study(study_file, storage_url), timeout=120, every=0.5)
    paused = start(_worker(study_file, storage_url, log, "--pause-at-first-heartbeat", marker))
    workers = [start(_worker(study_file, storage_url, log)) for _ in range(3)]

    mid_solve = _wait_for(lambda: _first_start_by(log, workers), timeout=120)
    _kill(mid_solve)
    workers.remove(mid_solve)
    workers.append(start(_worker(study_file, storage_url, log)))

    trial_id, paused_pid = _wait_for(lambda: marker.exists() and marker.read_text().split(), 120)
    _kill(paused)  # stopped between its claim and the claim's first heartbeat
    workers.append(start(_worker(study_file, storage_url, log)))

    _wait_for(lambda: _phases(study_file, storage_url) & {"iteration 1"}, timeout=240, every=0.5)
    _kill(planner)
    planner = start(_planner(study_file, storage_url))
    stdout, stderr = planner.communicate(timeout=400)
    assert planner.returncode == 0, stderr
    result = json.loads(stdout)
    for worker in workers:  # nothing is queued or running now: they stop cleanly
        worker.send_signal(signal.SIGTERM)
    for worker in workers:
        worker.communicate(timeout=60)
        assert worker.returncode in (0, 143)

    trials = _trials(study_file, storage_url)
    by_hash = collections.defaultdict(list)
    for trial in trials:
        by_hash[trial.user_attrs["input_hash"]].append(trial)
    finished = {
        key: [t for t in group if t.state == TrialState.COMPLETE or "reason" in t.user_attrs]
        for key, group in by_hash.items()
    }
    open_trials = [t for t in trials if t.state in (TrialState.RUNNING, TrialState.WAITING)]
    starts = [key for event, key, _ in events(log) if event == "start"]
    print(
        f"\n{storage_url.split(':')[0]}: {len(by_hash)} planned runs, {len(trials)} trials, "
        f"{sum(len(f) for f in finished.values())} finished, {len(open_trials)} running or "
        f"waiting, {len(starts)} solver starts (1 killed mid-solve), planner: "
        f"{result['status']} after {result['solver_calls']} runs"
    )
    # the trial claimed without a heartbeat was failed (never solved by its worker) and redone
    (claimed,) = [t for t in trials if t._trial_id == int(trial_id)]
    assert claimed.state == TrialState.FAIL and "reason" not in claimed.user_attrs
    assert not [pid for event, _, pid in events(log) if pid == int(paused_pid)]
    assert len(finished[claimed.user_attrs["input_hash"]]) == 1
    assert all(len(group) == 1 for group in finished.values()), finished
    assert not open_trials
    assert len(starts) == len(by_hash) + 1
    assert collections.Counter(starts).most_common(1)[0][1] <= 2
    assert result["status"] == "verified" and result["solver_calls"] == len(by_hash)
    assert _plan_by_phase(trials) == _uninterrupted_plan(study_file, tmp_path)


def _plan_by_phase(trials):
    plan = collections.defaultdict(set)
    for trial in trials:
        plan[trial.user_attrs["phase"]].add(trial.user_attrs["input_hash"])
    return dict(plan)


def _uninterrupted_plan(study_file, tmp_path):
    """The same study run in one process, never killed (its own folder and storage)."""
    import surrogate.identify._verify as verify_module
    from surrogate.identify._loop import run

    folder = tmp_path / "uninterrupted"
    folder.mkdir()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(verify_module, "solve_inputs", FixedCostSolve(folder / "log", 0.0))
        result = run(shutil.copy(study_file, folder), progress=False)
    return _plan_by_phase(_trials(folder / study_file.name, result.storage))


def _has_study(study_file, storage_url):
    try:
        return bool(_trials(study_file, storage_url))
    except KeyError:
        return False


def _phases(study_file, storage_url):
    return {t.user_attrs.get("phase") for t in _trials(study_file, storage_url)}
