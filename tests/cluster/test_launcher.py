"""The launcher's rules without a scheduler: ``[cluster]``, refusals before anything is
written, the storage the nodes reach, Slurm's words, and the fleet on a stand-in
launcher (the contract of ``surrogate/cluster/_launcher.py``, as PBS or LSF would be)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from surrogate._cli import main
from surrogate._errors import InputDataError, Interrupted
from surrogate.cluster import Demand, Fleet, JobRequest, JobState, jobs_to_submit
from surrogate.cluster._launcher import ENDED, PENDING, RUNNING
from surrogate.cluster._reach import unreachable_reason
from surrogate.cluster._slurm import batch_script, never_starts, parse_squeue
from surrogate.study._cluster import ClusterSettings
from surrogate.study._spec import load_study

STUDIES = Path(__file__).resolve().parents[2] / "studies"


def _study(tmp_path, cluster=""):
    text = (STUDIES / "paper_coating.toml").read_text() + cluster
    path = tmp_path / "paper_coating.toml"
    path.write_text(text)
    return path


def _refused(capsys, argv):
    """``surrogate ARGV`` exits 2 with one line on stderr; returns it."""
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


# -- [cluster] --------------------------------------------------------------------------------
def test_the_cluster_section_is_validated_like_every_other(tmp_path):
    spec = load_study(
        _study(
            tmp_path,
            '\n[cluster]\npartition = "compute"\naccount = "crash-01"\ntime_limit_min = 120\n'
            'cores = 16\nmemory_mb = 64000\nmax_jobs = 4\nsubmit_options = ["--qos=short"]\n'
            'modules = ["lsdyna/R13.1"]\nsetup = ["source /shared/venv/bin/activate"]\n',
        )
    )
    assert spec.cluster == ClusterSettings(
        "compute", "crash-01", 120, 16, 64000, 4, ("--qos=short",), "surrogate-",
        ("lsdyna/R13.1",), ("source /shared/venv/bin/activate",),
    )  # fmt: skip
    assert load_study(STUDIES / "paper_coating.toml").cluster == ClusterSettings()


@pytest.mark.parametrize(
    ("line", "said"),
    [
        ("queue = 'x'", "unknown key in [cluster] 'queue'; allowed: partition, account"),
        ("cores = 0", "cluster.cores must be a whole number ≥ 1, got 0"),
        ("max_jobs = 2.5", "cluster.max_jobs must be a whole number ≥ 1, got 2.5"),
        ("partition = 'a b'", "cluster.partition must be a name"),
        ("submit_options = ['qos=short']", "each starting with '-'), got 'qos=short'"),
        ("submit_options = '--qos=short'", "cluster.submit_options must be a list of strings"),
        ("modules = ['module load x']", "not a module name; put shell commands in cluster.setup"),
        ("job_name_prefix = 'my jobs'", "cluster.job_name_prefix must be up to 32"),
    ],
)
def test_a_bad_cluster_key_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, line, said):
    study = _study(tmp_path, f"\n[cluster]\n{line}\n")
    storage = tmp_path / "study.log"
    message = _refused(
        capsys, ["run", str(study), "--storage", str(storage), "--launcher", "slurm"]
    )
    assert said in message and str(study) in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper_coating.toml"]


# -- refused before anything is written -------------------------------------------------------
def test_no_sbatch_on_path_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "no-slurm-here"))
    study = _study(tmp_path)
    message = _refused(
        capsys, ["run", str(study), "--storage", f"{tmp_path}/s.log", "--launcher", "slurm"]
    )
    assert "--launcher slurm: sbatch, squeue, scontrol, scancel, sinfo not on PATH" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper_coating.toml"]


@pytest.mark.parametrize(
    ("storage", "said"),
    [
        (None, "SQLite hands the same queued run to two workers"),  # the study's default
        ("sqlite:///:memory:", "an in-memory SQLite database exists only inside this process"),
    ],
)
def test_a_storage_the_jobs_cannot_share_is_refused(tmp_path, capsys, storage, said):
    study = _study(tmp_path)
    where = [] if storage is None else ["--storage", storage]
    message = _refused(capsys, ["run", str(study), *where, "--launcher", "slurm"])
    assert said in message and "postgresql://" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper_coating.toml"]


def test_jobs_with_a_launcher_and_calibrate_of_a_built_in_study_are_refused(tmp_path, capsys):
    study = _study(tmp_path)
    log = f"{tmp_path}/s.log"
    message = _refused(
        capsys, ["run", str(study), "--storage", log, "--jobs", "2", "--launcher", "slurm"]
    )
    assert "--jobs 2 with --launcher slurm" in message
    webbing = STUDIES / "webbing_tests.toml"
    message = _refused(capsys, ["calibrate", str(webbing), "--storage", log, "--launcher", "slurm"])
    assert "full solver is the built-in one, whose runs take milliseconds" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper_coating.toml"]


@pytest.mark.parametrize(
    ("url", "storage_fs", "study_fs", "here", "refused"),
    [
        ("postgresql://me@127.0.0.1/db", None, "nfs4", True, None),  # a single-node cluster
        ("postgresql://me@127.0.0.1/db", None, "nfs4", False, "loopback"),
        ("postgresql://me@localhost/db", None, "nfs4", False, "loopback"),
        ("postgresql://me@dbhost/db", None, "nfs4", False, None),
        ("postgresql://me@dbhost/db", None, "ext4", False, "study folder is on a local disk"),
        ("journal:///scratch/s.log", "ext4", "nfs4", False, "journal is on a local disk (ext4)"),
        ("journal:///scratch/s.log", "tmpfs", "tmpfs", True, None),
        ("journal:///shared/s.log", "lustre", "lustre", False, None),
        ("journal:///shared/s.log", "fuse.sshfs", "gpfs", False, None),  # benefit of the doubt
        ("sqlite:////shared/s.db", None, "nfs4", True, "SQLite hands"),
    ],
)
def test_what_the_nodes_can_reach(url, storage_fs, study_fs, here, refused):
    reason = unreachable_reason(url, storage_fs=storage_fs, study_fs=study_fs, runs_here=here)
    assert (reason is None) if refused is None else (refused in reason)


# -- Slurm's words ----------------------------------------------------------------------------
def test_the_batch_script_carries_one_run_and_execs_the_worker(tmp_path):
    cluster = ClusterSettings(
        partition="compute", time_limit_min=90, cores=16, memory_mb=8000,
        modules=("lsdyna/R13",), setup=("source '/shared/my venv/bin/activate'",),
    )  # fmt: skip
    command = ("python", "-m", "surrogate", "worker", "/a b/s.toml")
    secret = {"SURROGATE_STORAGE": "postgresql://me:secret@db/x"}
    request = JobRequest("surrogate-s-1a2b3c", command, secret, tmp_path, cluster)
    script = batch_script(request)
    for line in (
        "#SBATCH --job-name=surrogate-s-1a2b3c",
        f"#SBATCH --output={tmp_path}/%x-%j.out",
        "#SBATCH --ntasks=16",
        "#SBATCH --signal=B:TERM@60",
        "#SBATCH --partition=compute",
        "#SBATCH --time=90",
        "#SBATCH --mem=8000M",
        "module load lsdyna/R13",
        "source '/shared/my venv/bin/activate'",
        'export SURROGATE_JOB_ID="$SLURM_JOB_ID"',
        "exec python -m surrogate worker '/a b/s.toml'",
    ):
        assert line in script.splitlines(), (line, script)
    assert "secret" not in script  # the storage is in the job's environment, not its script


def test_pending_reasons_that_are_never_left():
    assert "time_limit_min" in never_starts("PartitionTimeLimit")
    assert "account" in never_starts("InvalidAccount")
    assert "per-job limit" in never_starts("QOSMaxCpuPerJobLimit")
    assert "per-job limit" in never_starts("AssocMaxWallDurationPerJobLimit")
    assert "budget" in never_starts("AssocGrpCPUMinutesLimit")
    waited = ["Priority", "Resources", "ReqNodeNotAvail, UnavailableNodes:n1", "BeginTime"]
    waited += ["AssocGrpCPURunMinutesLimit", "AssocMaxJobsLimit", "QOSGrpCpuLimit"]
    waited += ["Nodes required for job are DOWN, DRAINED or reserved for jobs in higher …"]
    for reason in waited:
        assert never_starts(reason) is None, reason


def test_squeue_lines_become_job_states():
    jobs = parse_squeue("7|RUNNING|None\n8|PENDING|PartitionTimeLimit\n9|TIMEOUT|TimeLimit\n")
    assert [(j.job_id, j.phase, j.reason) for j in jobs] == [
        ("7", RUNNING, ""), ("8", PENDING, "PartitionTimeLimit"), ("9", ENDED, "TimeLimit"),
    ]  # fmt: skip
    assert jobs[1].never_starts is not None and jobs[0].never_starts is None
    assert not jobs[2].succeeded


# -- the fleet on a stand-in launcher ---------------------------------------------------------
class _Launcher:
    """A scheduler in memory: jobs are pending until ``start``, end with ``end``."""

    name = "stand-in"

    def __init__(self):
        self.states: dict[str, JobState] = {}
        self.finals: dict[str, JobState] = {}
        self.cancelled: list[str] = []

    def submit(self, request):
        job_id = str(100 + len(self.states))
        self.states[job_id] = JobState(job_id, PENDING, "PENDING", "Priority")
        return job_id

    def start(self, job_id):
        self.states[job_id] = JobState(job_id, RUNNING, "RUNNING")

    def end(self, job_id, state="COMPLETED", exit_code=0):
        ok = state == "COMPLETED" and exit_code == 0
        final = JobState(job_id, ENDED, state, exit_code=exit_code, succeeded=ok)
        self.states.pop(job_id)
        self.finals[job_id] = final

    def jobs(self, name):
        return list(self.states.values())

    def final(self, job_id):
        return self.finals.get(job_id)

    def cancel(self, job_ids):
        self.cancelled += job_ids
        for job_id in job_ids:
            self.states.pop(job_id, None)

    def log_file(self, request, job_id):
        return request.log_dir / f"{job_id}.out"


def _fleet(tmp_path, launcher, max_jobs=2, **options):
    request = JobRequest("jobs", ("worker",), {}, tmp_path, ClusterSettings(max_jobs=max_jobs))
    return Fleet(launcher, request, poll_s=0.0, label="s", stopped="stopped", **options)


def _demand(waiting, holders=(), finished=0):
    return lambda: Demand(waiting, frozenset(holders), finished)


@pytest.mark.parametrize(
    ("waiting", "alive", "holders", "max_jobs", "new"),
    [
        (3, [], [], 2, 2),
        (1, ["1"], [], 8, 0),
        (1, ["1"], ["1"], 8, 1),
        (5, ["1", "2"], ["1", "2"], 2, 0),
        (0, ["1"], [], 8, 0),
    ],
)
def test_a_job_for_each_queued_run_less_those_that_will_claim_one(
    waiting, alive, holders, max_jobs, new
):
    assert jobs_to_submit(waiting, alive, frozenset(holders), max_jobs) == new


def test_a_job_that_died_holding_a_run_is_replaced_once_its_run_is_queued(tmp_path, caplog):
    launcher = _Launcher()
    fleet = _fleet(tmp_path, launcher)
    fleet.tend(_demand(1))
    (job,) = launcher.states
    launcher.start(job)
    fleet.tend(_demand(0, holders=[job]))
    launcher.end(job, "NODE_FAIL", None)
    fleet.tend(_demand(0))  # its run not stale yet: no job for it
    assert list(launcher.states) == []
    fleet.tend(_demand(1))  # its copy is queued
    assert len(launcher.states) == 1
    assert f"stand-in job {job} ended NODE_FAIL" in caplog.text


def test_a_sigterm_whose_exception_was_lost_stops_the_next_look(tmp_path):
    """The SIGTERM handler's Interrupted raised where something swallows it (a storage
    retry around a PostgreSQL query): the fleet's next look raises it again."""
    fleet = _fleet(tmp_path, _Launcher())
    fleet.tend(_demand(0))
    with pytest.raises(Interrupted, match="stopped"):
        fleet._on_sigterm(signal.SIGTERM, None)
    with pytest.raises(Interrupted, match="stopped"):
        fleet.tend(_demand(1))


def test_a_worker_that_refused_to_start_stops_the_study_with_its_line(tmp_path):
    launcher = _Launcher()
    fleet = _fleet(tmp_path, launcher)
    fleet.tend(_demand(1))
    (job,) = launcher.states
    (tmp_path / f"{job}.out").write_text("surrogate: error: no study 's/verify' in …\n")
    launcher.end(job, "FAILED", 2)
    with pytest.raises(
        InputDataError, match=r"refused to start \(exit code 2\): surrogate: error: no"
    ):
        fleet.tend(_demand(1))


def test_jobs_that_keep_dying_before_taking_a_run_stop_the_study(tmp_path):
    launcher = _Launcher()
    fleet = _fleet(tmp_path, launcher, max_jobs=1)
    for k in range(4):
        fleet.tend(_demand(1, finished=1 if k == 2 else 0))  # a run finished once: reset
        (job,) = launcher.states
        (tmp_path / f"{job}.out").write_text("module: command not found\n")
        launcher.end(job, "FAILED", 1)
    fleet.tend(_demand(1, finished=1))
    (job,) = launcher.states
    launcher.end(job, "FAILED", 1)
    with pytest.raises(InputDataError, match="4 stand-in jobs in a row ended before their worker"):
        fleet.tend(_demand(1, finished=1))
    assert launcher.states == {}  # what was left is cancelled


def test_a_job_that_can_never_start_cancels_every_job_and_stops(tmp_path):
    launcher = _Launcher()
    fleet = _fleet(tmp_path, launcher)
    fleet.tend(_demand(2))
    first, second = launcher.states
    launcher.states[first] = JobState(first, PENDING, "PENDING", "PartitionTimeLimit",
                                      never_starts="lower [cluster] time_limit_min")  # fmt: skip
    with pytest.raises(InputDataError, match=f"job {first} can never start: PartitionTimeLimit"):
        fleet.tend(_demand(2))
    assert sorted(launcher.cancelled) == [first, second]


def test_the_end_cancels_what_is_pending_and_an_error_everything(tmp_path):
    launcher = _Launcher()
    with _fleet(tmp_path, launcher) as fleet:
        fleet.tend(_demand(2))
        first, second = launcher.states
        launcher.start(first)
    assert launcher.cancelled == [second, first]  # pending at once; running after linger_s 0
    launcher = _Launcher()
    with pytest.raises(RuntimeError), _fleet(tmp_path, launcher) as fleet:
        fleet.tend(_demand(1))
        raise RuntimeError("the planner failed")
    assert launcher.cancelled == ["100"]


def test_sigterm_stops_the_planner_and_cancels_its_jobs(tmp_path):
    launcher, before = _Launcher(), signal.getsignal(signal.SIGTERM)
    with (
        pytest.raises(Interrupted, match="stopped") as stopped,
        _fleet(tmp_path, launcher) as fleet,
    ):
        fleet.tend(_demand(1))
        os.kill(os.getpid(), signal.SIGTERM)
    assert stopped.value.signal_name == "SIGTERM" and launcher.cancelled == ["100"]
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is given back


def test_a_planner_started_again_takes_over_the_jobs_recorded(tmp_path):
    launcher = _Launcher()
    job = launcher.submit(None)
    launcher.start(job)
    recorded = [JobState(job, RUNNING, "RUNNING").to_json()]
    fleet = _fleet(tmp_path, launcher, history=[JobState.from_json(r) for r in recorded])
    fleet.tend(_demand(0, holders=[job]))
    assert list(launcher.states) == [job]  # no second job for its run
    launcher.end(job)
    fleet.tend(_demand(0))
    fleet.cancel_all()
    assert fleet.history[job].state == "COMPLETED" and launcher.cancelled == []


# -- surrogate status -------------------------------------------------------------------------
def test_status_counts_a_queue_and_lists_its_jobs_as_recorded(tmp_path, capsys, monkeypatch):
    """Where Slurm's commands do not answer (not on PATH here), the jobs as the planner
    last recorded them, with the trial each running one holds."""
    import json

    import optuna

    from surrogate.identify._doe import make_design
    from surrogate.identify._jobs import JOBS_ATTR
    from surrogate.identify._verify import enqueue, open_verify_study
    from surrogate.identify._worker import JOB_ATTR

    study_file, storage = _study(tmp_path), f"journal://{tmp_path / 'study.log'}"
    spec = load_study(study_file)
    study = open_verify_study(spec, storage, heartbeat_s=None)
    enqueue(study, spec, make_design("lhs", spec.space, n=2, seed=0).to_dict("records"), phase="p")
    claimed = study.get_trials(deepcopy=False)[0]._trial_id
    study._storage.set_trial_state_values(claimed, optuna.trial.TrialState.RUNNING)
    study._storage.set_trial_system_attr(claimed, JOB_ATTR, "7")
    jobs = [JobState("7", RUNNING, "RUNNING").to_json(), JobState("6", ENDED, "TIMEOUT").to_json()]
    study.set_user_attr(JOBS_ATTR, {"launcher": "slurm", "job_name": "surrogate-x", "jobs": jobs})
    monkeypatch.setenv("PATH", str(tmp_path / "no-slurm-here"))
    main(["status", str(study_file), "--storage", storage, "--json"])
    shown = json.loads(capsys.readouterr().out)
    assert shown["queues"]["paper-coating/verify"] == {
        "queued": 1, "running": 1, "finished": 0, "ok": 0, "failed": 0, "given_back": 0
    }  # fmt: skip
    assert [(j["job_id"], j["state"], j["run"]) for j in shown["jobs"]] == [
        ("7", "RUNNING", 0),
        ("6", "TIMEOUT", None),
    ]
    assert shown["live"] is False
    main(["status", str(study_file), "--storage", storage])
    assert "jobs (as last recorded; the scheduler is not here)" in capsys.readouterr().out
