"""The main job: ``surrogate run`` on the built-in solver with a real SQLite storage."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest

import surrogate
import surrogate.identify._verify as verify_module
from surrogate import InputDataError, load_study
from surrogate.identify._loop import run
from tests.conftest import CountingSolve

STUDIES = Path(__file__).resolve().parents[1] / "studies"
OPTUNA = str(Path(sys.executable).with_name("optuna"))  # the optuna CLI of this environment
pytestmark = pytest.mark.slow


@pytest.fixture
def study_file(tmp_path):
    (tmp_path / "studies").mkdir()
    path = tmp_path / "studies" / "paper_coating.toml"
    shutil.copy(STUDIES / "paper_coating.toml", path)
    return path


def test_verified_point_resimulated_meets_target_and_constraints(study_file):
    result = run(study_file, progress=False)
    spec = load_study(study_file)
    assert result.status == "verified"
    assert result.calls_to_verify <= spec.budget.max_solver_calls
    assert result.solver_calls == result.calls_to_verify + 3  # exact sensitivities
    assert result.identifiability["exponents_from"] == "full solver"
    v = result.verified
    curve = surrogate.simulate(v["ecoat_gpa"], v["scoat_gpa"], v["tcoat_mm"])
    assert abs(curve.f60_n / spec.targets.f60_n - 1) <= spec.targets.tolerance
    assert curve.theta_sat_deg >= spec.constraints.theta_sat_deg_min
    assert v["tcoat_mm"] <= 0.1 * spec.rig.thickness_mm
    assert curve.f60_n == pytest.approx(v["f60_n"], rel=1e-9)
    ident = result.identifiability
    assert abs(ident["exponents"]["ecoat_gpa"]) > 0.8 and abs(ident["exponents"]["tcoat_mm"]) > 0.8
    assert abs(ident["exponents"]["scoat_gpa"]) < 0.2  # elastic at the target: D = E·T matters
    assert "bending stiffness" in ident["statement"]
    # the study in storage: one trial per solver call, the dashboard report attached
    study = optuna.load_study(study_name="paper-coating/verify", storage=result.storage)
    assert len(study.trials) == result.solver_calls
    best = study.best_trial  # constrained: only feasible trials count
    assert all(value <= 0 for value in best.constraints.values())
    attrs = study._storage.get_study_system_attrs(study._study_id)  # where the dashboard looks
    assert any(key.startswith("dashboard:plot_data:verified-curves") for key in attrs)
    assert any("note" in key for key in attrs)


def _finished_hashes(storage):
    study = optuna.load_study(study_name="paper-coating/verify", storage=storage)
    return [
        t.user_attrs["input_hash"]
        for t in study.trials
        if t.state == optuna.trial.TrialState.COMPLETE
    ]


def test_interrupted_run_resumes_the_same_plan_without_repeating(study_file, tmp_path, monkeypatch):
    """Interrupted after the initial design and three iterations, then run
    again: the same runs in the same order as a run never interrupted, none twice."""
    stop_after = 8
    monkeypatch.setattr(verify_module, "solve_inputs", CountingSolve(stop_after=stop_after))
    with pytest.raises(KeyboardInterrupt):
        run(study_file, progress=False)
    storage = load_study(study_file).default_storage()
    assert len(set(_finished_hashes(storage))) == stop_after
    shutil.rmtree(study_file.parent / ".solver-cache")  # only the storage remembers now
    second = CountingSolve()
    monkeypatch.setattr(verify_module, "solve_inputs", second)
    result = run(study_file, progress=False)
    assert result.status == "verified"
    assert second.calls == result.solver_calls - stop_after
    hashes = _finished_hashes(storage)
    assert len(hashes) == len(set(hashes)) == result.solver_calls

    (tmp_path / "once").mkdir()
    once = run(shutil.copy(study_file, tmp_path / "once" / study_file.name), progress=False)
    assert _finished_hashes(once.storage) == hashes
    assert once.verified == result.verified and once.calls_to_verify == result.calls_to_verify


def test_optuna_cli_lists_verify_trials_with_constraints(study_file):
    result = run(study_file, progress=False, budget=10)
    listing = subprocess.run(
        [OPTUNA, "trials", "--storage", result.storage, "--study-name", result.study, "-f", "json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert listing.returncode == 0, listing.stderr
    trials = json.loads(listing.stdout)
    assert len(trials) == result.solver_calls
    assert all(set(trial["value"]) == {"f60_relative_misfit"} for trial in trials)
    for trial in trials:
        assert set(trial["user_attrs"]["constraints"]) == {"theta_sat_min", "tcoat_max"}
        assert "f60_n" in trial["user_attrs"] and "theta_sat_deg" in trial["user_attrs"]
    study = optuna.load_study(study_name=result.study, storage=result.storage)
    for trial in study.trials:  # both formats: Optuna 5's and optuna-dashboard 0.21's list
        assert trial.system_attrs["constraints"] == list(trial.user_attrs["constraints"].values())
        assert (
            trial.system_attrs["constraints:theta_sat_min"]
            == trial.user_attrs["constraints"]["theta_sat_min"]
        )
    studies = subprocess.run(
        [OPTUNA, "studies", "--storage", result.storage, "-f", "json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "paper-coating/verify" in studies.stdout and "f60_relative_misfit" in studies.stdout


def test_infeasible_target_ends_budget_exhausted_with_an_explanation(study_file):
    result = run(study_file, progress=False, target=500.0, budget=10)
    assert result.status == "budget_exhausted"
    assert result.solver_calls == 10
    assert "out of reach" in result.message and "500" in result.message
    assert result.verified is not None  # the best verified point is still reported


def test_a_search_with_nothing_new_to_verify_ends_stalled_not_budget_exhausted(
    study_file, monkeypatch
):
    """The loop stops with runs left where the search proposes no point it has not
    verified (scripted here after the initial design): the status says the budget was not
    the limit, not that it was spent."""
    monkeypatch.setattr(
        "surrogate.identify._loop._propose", lambda *args, n, **kwargs: np.empty((0, 3))
    )
    result = run(study_file, progress=False, target=500.0, budget=10)
    assert result.status == "stalled", result.message
    assert result.solver_calls < 10 and result.verified is not None
    assert f"stalled after {result.solver_calls} of 10 runs" in result.message
    assert "a larger budget would not have been spent" in result.message
    assert "budget exhausted" not in result.message
    with pytest.raises(InputDataError, match="stalled with runs left"):
        surrogate.export(study_file, output=study_file.parent / "coat.k")
    assert not (study_file.parent / "coat.k").exists()


def test_cli_run_json(study_file):
    completed = subprocess.run(
        [
            sys.executable,
            "-m",
            "surrogate",
            "run",
            str(study_file),
            "--json",
            "--budget",
            "12",
            "--seed",
            "3",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert completed.returncode == 0, completed.stderr
    payload = json.loads(completed.stdout)
    assert set(payload) >= {
        "status",
        "solver_calls",
        "verified",
        "study",
        "storage",
        "identifiability",
    }
    assert payload["status"] in ("verified", "budget_exhausted", "stalled")
    if payload["status"] == "verified":
        assert set(payload["verified"]) == {
            "ecoat_gpa",
            "scoat_gpa",
            "tcoat_mm",
            "f60_n",
            "theta_sat_deg",
        }


def test_run_needs_a_scalar_target(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[study]\nname = "m"\n[measurements]\nfile = "m.csv"\n')
    with pytest.raises(InputDataError, match="needs \\[targets\\] f60_n"):
        run(path, progress=False)


def test_a_point_queued_by_a_killed_worker_planner_is_solved_into_its_own_trial(
    study_file, monkeypatch
):
    """A `run --jobs 4` planner killed with runs queued, then `run` in one process: each
    result lands in the trial of its own input hash, none in another queued one."""
    from surrogate.identify._verify import Verifier, enqueue, open_verify_study

    spec = load_study(study_file)
    study = open_verify_study(spec, spec.default_storage(), heartbeat_s=None)
    points = [
        {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012},
        {"ecoat_gpa": 2.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012},
    ]
    keys = enqueue(study, spec, points, phase="iteration 1")  # left WAITING by the dead planner
    verifier = Verifier(spec, study, progress=False, replay=True)
    record = verifier.solve(points[1], phase="iteration 1")  # the second point first
    trials = {t.user_attrs["input_hash"]: t for t in study.get_trials(deepcopy=False)}
    assert len(trials) == 2  # no new trial: the queued one was claimed
    done = trials[keys[1]]
    assert done.state == optuna.trial.TrialState.COMPLETE
    assert done.params == pytest.approx(points[1])
    assert done.user_attrs["f60_n"] == pytest.approx(record.f60_n)
    assert record.f60_n == pytest.approx(surrogate.simulate(**points[1]).f60_n)
    assert trials[keys[0]].state == optuna.trial.TrialState.WAITING
