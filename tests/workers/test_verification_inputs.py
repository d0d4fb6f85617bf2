"""A multi-worker run and an in-process run of a study with solver settings make the
same trials: the workers solve with the study's ``[solver]`` settings and name each
run by the same hash as the planner, so no run is solved twice or with other settings."""

from __future__ import annotations

import collections
import os
from typing import Any, ClassVar

import optuna
import pytest
from optuna.trial import TrialState

import surrogate
from surrogate.solvers import get_solver
from surrogate.solvers._base import _REGISTRY, Solver
from surrogate.solvers._cache import input_hash
from surrogate.storage import open_storage

LOG_VARIABLE = "SURROGATE_TEST_SOLVER_LOG"


class ScaledSolver(Solver):
    """Test only: the built-in solver's curve times the setting ``scale`` (default 1),
    logging the hash of every run it solves to the file named by $SURROGATE_TEST_SOLVER_LOG."""

    name: ClassVar[str] = "test-scaled"
    version: ClassVar[str] = "test-1"
    settings_keys: ClassVar[tuple[str, ...]] = ("scale",)

    def solve(self, inputs: dict[str, Any]) -> dict[str, Any]:
        with open(os.environ[LOG_VARIABLE], "a", encoding="utf-8") as log:
            log.write(f"{input_hash(inputs)}\n")
        scale = float((inputs.get("solver_settings") or {}).get("scale", 1.0))
        plain = {k: v for k, v in inputs.items() if k != "solver_settings"}
        result = get_solver("builtin").solve({**plain, "solver": "builtin"})
        for key in ("force_n", "force_perp_n"):
            result[key] = [scale * f for f in result[key]]
        result["f60_n"] *= scale
        return result


@pytest.fixture
def scaled_solver(monkeypatch):
    monkeypatch.setitem(_REGISTRY, ScaledSolver.name, ScaledSolver)


STUDY = """
[study]
name = "scaled"
seed = 0

[solver]
kind = "test-scaled"
scale = 2.0
multi_fidelity = false   # the loop of the study's own solver (tests/test_fidelity.py: the other)

[targets]
f60_n = 19.9
tolerance = 0.05

[budget]
initial_samples = 4
max_solver_calls = 9
surrogate_trials = 100
identifiability_runs = 0
"""


def _run(folder, storage: str, jobs: int, monkeypatch) -> tuple[Any, list[Any], list[str]]:
    folder.mkdir()
    study = folder / "scaled.toml"
    study.write_text(STUDY)
    log = folder / "solver.log"
    monkeypatch.setenv(LOG_VARIABLE, str(log))
    result = surrogate.run(study, storage=storage, jobs=jobs, progress=False)
    trials = optuna.load_study(
        study_name="scaled/verify", storage=open_storage(storage)
    ).get_trials()
    return result, trials, log.read_text().split()


def _summary(trials) -> list[tuple[Any, ...]]:
    return [
        (
            t.state,
            tuple(sorted(t.params.items())),
            t.value,
            t.user_attrs.get("input_hash"),
            t.user_attrs.get("phase"),
            t.user_attrs.get("f60_n"),
        )
        for t in sorted(trials, key=lambda t: t.user_attrs["input_hash"])
    ]


def test_workers_and_the_planner_solve_the_same_runs_with_the_study_settings(
    tmp_path, scaled_solver, monkeypatch, storage_url
):
    sqlite = f"sqlite:///{tmp_path / 'alone' / 'scaled.db'}"
    alone, alone_trials, alone_log = _run(tmp_path / "alone", sqlite, 1, monkeypatch)
    # two local worker processes, forked by the planner (on PostgreSQL: it holds a pool)
    shared, shared_trials, shared_log = _run(tmp_path / "workers", storage_url, 2, monkeypatch)

    assert alone.solver_calls == shared.solver_calls == len(alone_trials) >= 5
    assert _summary(shared_trials) == _summary(alone_trials)
    assert all(t.state == TrialState.COMPLETE for t in shared_trials)
    # every run solved once, with the settings: the hash the trial carries is the one solved
    assert collections.Counter(shared_log) == {t.user_attrs["input_hash"]: 1 for t in shared_trials}
    assert sorted(shared_log) == sorted(alone_log)
    # and the setting took effect in the workers: F60 is twice the built-in's
    trial = shared_trials[0]
    plain = surrogate.simulate(**trial.params)
    assert trial.user_attrs["f60_n"] == pytest.approx(2.0 * plain.f60_n, rel=1e-12)


def _plan(folder, storage: str, n: int) -> tuple[Any, list[str]]:
    from surrogate.identify._doe import make_design
    from surrogate.identify._verify import enqueue, open_verify_study
    from surrogate.study._spec import load_study

    folder.mkdir()
    (folder / "scaled.toml").write_text(STUDY)
    spec = load_study(folder / "scaled.toml")
    study = open_verify_study(spec, storage, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=n, seed=0).to_dict("records")
    return spec, enqueue(study, spec, points, phase="plan")


def test_a_worker_with_another_solver_version_fails_the_runs_instead_of_solving_others(
    tmp_path, scaled_solver, monkeypatch
):
    from surrogate.identify._verify import finished_records, open_verify_study
    from surrogate.identify._worker import work

    storage = f"journal://{tmp_path / 'study.log'}"
    spec, keys = _plan(tmp_path / "plan", storage, 3)
    monkeypatch.setenv(LOG_VARIABLE, str(tmp_path / "solver.log"))
    monkeypatch.setattr(ScaledSolver, "version", "test-2")  # this worker's solver is newer
    result = work(spec, storage=storage, idle_timeout_s=0.0, progress=False)

    assert (result.runs, result.failed, result.solved) == (3, 3, 0)
    assert not (tmp_path / "solver.log").exists()  # nothing else was solved
    records = finished_records(open_verify_study(spec, storage, heartbeat_s=None), keys)
    assert sorted(records) == sorted(keys)  # the planner stops waiting: every run is over
    assert all("differ from the planner's" in r.reason for r in records.values())


def test_a_worker_whose_study_file_has_other_solver_settings_is_refused(tmp_path, scaled_solver):
    from surrogate.identify._worker import work

    storage = f"journal://{tmp_path / 'study.log'}"
    _plan(tmp_path / "plan", storage, 2)
    other = tmp_path / "other.toml"
    other.write_text(STUDY.replace("scale = 2.0", "scale = 3.0"))
    with pytest.raises(surrogate.InputDataError, match=r"its \[solver\] differs from the plan"):
        work(other, storage=storage, idle_timeout_s=0.0, progress=False)
