"""``--launcher slurm`` on a real single-node Slurm, with the faults a cluster has.

The cluster is Debian's slurm-wlm and munge started for the session (``conftest.py``);
the storage a throwaway PostgreSQL on 127.0.0.1 (the journal for the calibration) —
both reachable by the jobs because the cluster's only node is this machine. The full
solver is the LS-DYNA stand-in (``tests/solvers/fixtures/fake_lsdyna.py``, NOT
LS-DYNA) started by ``srun`` inside each job, slowed to ``SLEEP_S`` a run so a test can
strike mid-solve; it is the built-in solver's physics, so the multi-fidelity study
verifies with its first expensive run (one job a study, a fast test). Each fault
ends with: the study verified, every planned run finished exactly once (0 lost), no
run's solve finished twice, nothing queued or running in the storage, and no job left
in Slurm's queue.
"""

from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest

from surrogate.storage._storage import open_storage
from tests.cluster.conftest import lsdyna_study
from tests.workers.test_workers import _wait_for

pytestmark = [pytest.mark.slurm, pytest.mark.slow]
REPO = Path(__file__).resolve().parents[2]
SLEEP_S = 1.5
TrialState = optuna.trial.TrialState


# -- helpers ----------------------------------------------------------------------------------
def _planner(command, study_file, storage, log, *extra, sleep_s=SLEEP_S):
    """``surrogate COMMAND STUDY --storage URL --launcher slurm --heartbeat 1 --json``."""
    environment = {**os.environ, "FAKE_LSDYNA_LOG": str(log), "FAKE_LSDYNA_SLEEP_S": str(sleep_s)}
    return subprocess.Popen(
        [sys.executable, "-m", "surrogate", command, str(study_file), "--storage", storage,
         "--launcher", "slurm", "--heartbeat", "1", "--json", *extra],
        cwd=REPO, env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _events(log):
    """``(event, key, job)`` per line the stand-in wrote."""
    if not Path(log).exists():
        return []
    return [
        (e, k, j) for e, k, _, j in (line.split() for line in Path(log).read_text().splitlines())
    ]


def _first_solve(log):
    """The job of the first solve that started, once one has."""
    starts = [job for event, _, job in _events(log) if event == "start"]
    return starts[0] if starts else None


def _worker_pid(job_id):
    """The pid of job ``job_id``'s worker (the batch shell, exec'd into `surrogate worker`)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().split(b"\0")
            environment = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"worker" in command and f"SURROGATE_JOB_ID={job_id}".encode() in environment:
            return int(entry.name)
    return None


def _queue(*options):
    listed = subprocess.run(
        ["squeue", "-h", *options, "-o", "%i|%T|%r|%j"], capture_output=True, text=True, check=True
    )
    return [line.split("|") for line in listed.stdout.splitlines()]


def _alive_jobs():
    return [job for job in _queue("--states=PENDING,RUNNING,CONFIGURING,COMPLETING,SUSPENDED")]


def _finish(planner, timeout=300):
    stdout, stderr = planner.communicate(timeout=timeout)
    return planner.returncode, stdout, stderr


def _trials(study_file, storage, queue="verify"):
    name = f"{Path(study_file).stem}/{queue}"
    return optuna.load_study(study_name=name, storage=open_storage(storage)).get_trials()


def _assert_each_run_once(study_file, storage, log, *, struck, queue="verify"):
    """Every run finished exactly once, nothing open; each solve finished at most once;
    the solver started ``struck`` times more than it finished (the solves struck)."""
    trials = _trials(study_file, storage, queue)
    finished = collections.Counter(
        t.user_attrs["input_hash"]
        for t in trials
        if t.state == TrialState.COMPLETE or "reason" in t.user_attrs
    )
    keys = {t.user_attrs["input_hash"] for t in trials}
    assert finished == collections.Counter(keys), "a run lost or finished twice"
    assert not [t for t in trials if t.state in (TrialState.RUNNING, TrialState.WAITING)]
    events = _events(log)
    done = collections.Counter(key for event, key, _ in events if event == "done")
    assert max(done.values()) == 1, f"a run solved twice: {done}"
    starts = sum(event == "start" for event, _, _ in events)
    assert len(done) == len(keys) and starts == len(keys) + struck, events
    _wait_for(lambda: not _alive_jobs(), 30, 0.5)  # no job left in the queue
    return trials


def _verified(stdout):
    result = json.loads(stdout)
    assert result["status"] == "verified", result["message"]
    return result


# -- the faults -------------------------------------------------------------------------------
def test_a_worker_killed_mid_solve_costs_its_run_once(tmp_path, postgres_url, clean_queue):
    """SIGKILL to a job's worker mid-solve: the job ends FAILED, the run goes stale (three
    heartbeats), its copy is queued and a new job solves it."""
    study, log = lsdyna_study(tmp_path), tmp_path / "solves.log"
    planner = _planner("run", study, postgres_url, log)
    job = _wait_for(lambda: _first_solve(log), 120, 0.2)
    os.kill(_wait_for(lambda: _worker_pid(job), 30, 0.1), signal.SIGKILL)
    code, stdout, stderr = _finish(planner)
    assert code == 0, stderr
    _verified(stdout)
    _assert_each_run_once(study, postgres_url, log, struck=1)
    assert [state for job_id, state, *_ in _queue("--states=all") if job_id == job] == ["FAILED"]
    assert f"slurm job {job} ended FAILED" in stderr


def test_a_job_signalled_before_its_limit_and_a_job_cancelled_give_their_runs_back(
    tmp_path, postgres_url, clean_queue
):
    """What ``--signal=B:TERM@60`` sends before the time limit (SIGTERM to the batch shell,
    the worker: ``scancel --batch --signal=TERM``), then ``scancel`` (SIGTERM to every
    process of the job): each worker gives its run back at once, a new job redoes it."""
    study, log = lsdyna_study(tmp_path), tmp_path / "solves.log"
    planner = _planner("run", study, postgres_url, log)
    first = _wait_for(lambda: _first_solve(log), 120, 0.2)
    subprocess.run(["scancel", "--batch", "--signal=TERM", first], check=True)
    second = _wait_for(
        lambda: [j for e, _, j in _events(log) if e == "start" and j != first], 120, 0.2
    )[0]
    subprocess.run(["scancel", second], check=True)
    code, stdout, stderr = _finish(planner)
    assert code == 0, stderr
    _verified(stdout)
    trials = _assert_each_run_once(study, postgres_url, log, struck=2)
    given_back = [t.system_attrs.get("interrupted") for t in trials if t.state == TrialState.FAIL]
    assert given_back == ["SIGTERM", "SIGTERM"]  # given back by the workers, not gone stale
    states = {job_id: state for job_id, state, *_ in _queue("--states=all")}
    assert states[first] == "FAILED" and states[second] == "CANCELLED"  # exit 143; scancel


def test_a_drained_node_holds_the_job_until_it_is_resumed(tmp_path, postgres_url, clean_queue):
    """The node drained (``scontrol update … state=drain``): the job waits with a reason it
    can leave (the node's), the planner waits with it, and goes on once it is resumed."""
    study, log = lsdyna_study(tmp_path), tmp_path / "solves.log"
    node = clean_queue["node"]
    drain = ["scontrol", "update", f"nodename={node}", "state=drain", "reason=maintenance"]
    subprocess.run(drain, check=True)
    planner = _planner("run", study, postgres_url, log)
    held = _wait_for(lambda: [j for j in _queue("--states=PENDING") if "DRAINED" in j[2]], 120, 0.5)
    time.sleep(3.0)  # three polls of the planner: it waits, it does not stop
    assert planner.poll() is None and not _events(log), held
    subprocess.run(["scontrol", "update", f"nodename={node}", "state=resume"], check=True)
    code, stdout, stderr = _finish(planner)
    assert code == 0, stderr
    _verified(stdout)
    _assert_each_run_once(study, postgres_url, log, struck=0)
    assert held[0][0] == _first_solve(log)


def test_a_planner_stopped_or_killed_and_started_again(tmp_path, postgres_url, clean_queue):
    """SIGTERM to the planner while its job solves: it cancels its job (whose worker gives
    the run back) and stops with one line, exit code 143. Started again, it submits a job
    for the run; SIGKILLed while that one solves and started again with the same command,
    it finds the job by its name and waits for it (no second job for the run). Then
    ``surrogate status`` lists the jobs."""
    study, log = lsdyna_study(tmp_path), tmp_path / "solves.log"
    planner = _planner("run", study, postgres_url, log)
    first = _wait_for(lambda: _first_solve(log), 120, 0.2)
    planner.send_signal(signal.SIGTERM)
    code, _, stderr = _finish(planner, 60)
    assert code == 143 and "stopped by SIGTERM: its slurm jobs are cancelled" in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("surrogate: 'belt' stopped by SIGTERM")
    planner = _planner("run", study, postgres_url, log)
    second = _wait_for(
        lambda: [j for e, _, j in _events(log) if e == "start" and j != first], 120, 0.2
    )[0]
    planner.kill()
    planner.wait(timeout=30)
    code, stdout, stderr = _finish(_planner("run", study, postgres_url, log))
    assert code == 0, stderr
    _verified(stdout)
    _assert_each_run_once(study, postgres_url, log, struck=1)
    states = {job_id: state for job_id, state, *_ in _queue("--states=all")}
    assert (states[first], states[second]) == ("CANCELLED", "COMPLETED")
    shown = subprocess.run(
        [sys.executable, "-m", "surrogate", "status", str(study), "--storage", postgres_url],
        cwd=REPO, capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "belt/verify: 0 queued, 0 running" in shown.stdout, shown.stdout
    rows = [line.split() for line in shown.stdout.splitlines() if line.split()[0].isdigit()]
    listed = {row[0]: row[1].rstrip(",") for row in rows}
    assert (listed[first], listed[second]) == ("CANCELLED", "COMPLETED"), shown.stdout


# -- what stops the study ---------------------------------------------------------------------
def test_a_job_that_can_never_start_stops_the_study_in_one_line(tmp_path, postgres_url,
                                                                clean_queue):  # fmt: skip
    """A time limit over the partition's (sbatch accepts it; Slurm keeps it pending for
    ``PartitionTimeLimit`` for ever): one line, exit code 2, its job cancelled."""
    study = lsdyna_study(tmp_path, cluster='partition = "short"\ntime_limit_min = 5\n')
    code, _, stderr = _finish(_planner("run", study, postgres_url, tmp_path / "s.log"), 120)
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert "can never start: PartitionTimeLimit" in lines[-1], stderr
    assert "time_limit_min" in lines[-1]
    _wait_for(lambda: not _alive_jobs(), 30, 0.5)


def test_a_partition_slurm_does_not_know_is_refused_before_anything_is_written(tmp_path):
    """``sbatch --test-only`` refuses it: one line, exit code 2, no storage, no job folder."""
    study = lsdyna_study(tmp_path, cluster='partition = "nowhere"\n')
    storage = f"journal://{tmp_path / 'study.log'}"
    code, _, stderr = _finish(_planner("run", study, storage, tmp_path / "s.log"), 60)
    assert code == 2
    assert stderr.strip().count("\n") == 0 and "invalid partition" in stderr, stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["belt.toml"]


# -- calibrate: the expensive runs through the run queue --------------------------------------
def test_calibrate_sends_its_lsdyna_runs_to_slurm_jobs(tmp_path, clean_queue):
    """``calibrate --launcher slurm``: the stand-in's runs are jobs, the built-in prior's
    stay in the planner; at the noise floor, each run once, no job left."""
    import numpy as np

    import surrogate

    curve = surrogate.simulate(1.0, 0.2, 0.012)
    rng = np.random.default_rng(0)
    rows = ["test_id,angle_deg,force_n"] + [
        f"{test},{a:g},{f + rng.normal(0, 0.05):.4f}"
        for test in ("T1", "T2")
        for a, f in zip(curve.angle_deg, curve.force_n, strict=True)
        if a % 2 == 0
    ]
    (tmp_path / "curves.csv").write_text("\n".join(rows) + "\n")
    study = lsdyna_study(tmp_path)
    text = study.read_text().replace(
        "[targets]\nf60_n = 9.958\n", '[measurements]\nfile = "curves.csv"\n'
    )
    study.write_text(text)
    storage, log = f"journal://{tmp_path / 'study.log'}", tmp_path / "solves.log"
    code, stdout, stderr = _finish(_planner("calibrate", study, storage, log, sleep_s=0))
    assert code == 0, stderr
    result = json.loads(stdout)
    assert result["rmse_n"] < 1.3 * 0.05, result["message"]
    trials = _assert_each_run_once(study, storage, log, struck=0, queue="runs")
    # its own runs and the checks of its profile ends (at most 10, on top of its budget)
    checks = (result["determination"] or {}).get("verification_solver_calls") or 0
    assert len(trials) == result["solver_calls"] + checks and result["solver_calls"] > 0
