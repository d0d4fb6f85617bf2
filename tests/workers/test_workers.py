"""Many workers on one storage: every run exactly once, faults cost one run at most.

Workers are real processes (``python -m tests.workers.fixed_cost``) running
``surrogate.identify._worker.work`` with the fixed-cost stand-in solver, on the journal
file and on a throwaway PostgreSQL server.
"""

from __future__ import annotations

import collections
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest

from surrogate.identify._doe import make_design
from surrogate.identify._verify import enqueue, open_verify_study
from surrogate.identify._worker import work
from surrogate.storage._storage import open_storage
from surrogate.study._spec import load_study
from tests.workers.fixed_cost import FixedCostSolve, events

REPO = Path(__file__).resolve().parents[2]
STUDIES = REPO / "studies"
pytestmark = pytest.mark.slow
TrialState = optuna.trial.TrialState


@pytest.fixture
def study_file(tmp_path):
    path = tmp_path / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", path)
    return path


def _plan(study_file, storage_url, n):
    spec = load_study(study_file)
    study = open_verify_study(spec, storage_url, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=n, seed=3).to_dict("records")
    return enqueue(study, spec, points, phase="plan")


def _worker(study_file, storage_url, log, cost_s, *, jobs=1):
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.workers.fixed_cost",
            str(study_file),
            storage_url,
            str(log),
            str(cost_s),
            str(jobs),
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _trials(study_file, storage_url):
    spec = load_study(study_file)
    study = optuna.load_study(study_name=f"{spec.name}/verify", storage=open_storage(storage_url))
    return study.get_trials(deepcopy=False)


def _wait_all(processes, timeout=120):
    for process in processes:
        _, stderr = process.communicate(timeout=timeout)
        assert process.returncode == 0, stderr


def _wait_for(condition, timeout=60):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError("timed out")


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
