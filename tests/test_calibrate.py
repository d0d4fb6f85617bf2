"""Calibration against measured curves, and the comparison of model and measurements.

Data are made by the built-in solver with seeded noise (surrogate.calibration._synthetic);
the truth is known to the test, never to the calibration.
"""

import json

import numpy as np
import optuna
import pytest

import surrogate
from surrogate._cli import main
from surrogate._errors import InputDataError
from surrogate.calibration._calibrate import run_calibration
from surrogate.calibration._synthetic import synthetic_measurements
from surrogate.physics import bending_stiffness, plastic_moment
from surrogate.storage._storage import open_storage
from tests.studies import write_study

TRUTH = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
NOISE = 0.05
T = 1.2  # webbing thickness [mm]


def _study(
    tmp_path, tests, *, effects=None, hidden=None, seed=1, name="cal", budget=200, noise=None
):
    table = synthetic_measurements(tests, coating=TRUTH, effects=hidden, noise_n=NOISE, seed=seed)
    listed = ", ".join(f'"{e}"' for e in (effects or []))
    return write_study(
        tmp_path,
        table,
        f"""
        [study]
        name = "{name}"
        [measurements]
        file = "tests.csv"
        {"" if noise is None else f"noise_n = {noise}"}
        [model]
        effects = [{listed}]
        [budget]
        calibration_solver_calls = {budget}
        surrogate_trials = 100
        """,
        ranges=True,
    )


def _stiffness_and_moment(params):
    e, s, t = (params[k] * f for k, f in (("ecoat_gpa", 1e3), ("scoat_gpa", 1e3), ("tcoat_mm", 1)))
    return bending_stiffness(e, t, T), plastic_moment(s, t, T)


BASE_TESTS = [
    {"test_id": "a1", "tension_n": 0.0, "temperature_c": 21.0},
    {"test_id": "a2", "tension_n": 0.0, "temperature_c": 24.0},
    {"test_id": "b1", "tension_n": 20.0, "temperature_c": 22.5},
    {"test_id": "b2", "tension_n": 20.0, "temperature_c": 23.0},
]


@pytest.mark.slow
def test_base_model_on_base_data_recovers_the_identifiable_combination(tmp_path):
    path = _study(tmp_path, BASE_TESTS)
    result = surrogate.calibrate(path, progress=False)
    # the noise comes from the two replicate pairs
    assert result.noise_n == pytest.approx(NOISE, rel=0.15)
    # RMSE ≈ noise: within 3 % of the RMSE of the truth itself on these noisy data
    at_truth = surrogate.compare(path, params=TRUTH, plots=False, progress=False).rmse_n
    assert result.rmse_n <= 1.03 * at_truth
    assert at_truth == pytest.approx(NOISE, rel=0.1)
    # the curve fixes D ∝ Ecoat·Tcoat and Mp ∝ Scoat·Tcoat, not the three values apart
    d, mp = _stiffness_and_moment(result.params)
    d0, mp0 = _stiffness_and_moment(TRUTH)
    assert d == pytest.approx(d0, rel=0.03)
    assert mp == pytest.approx(mp0, rel=0.03)
    assert result.status == "converged"
    assert 0 < result.solver_calls <= 200
    assert result.effects == []
    # the verifications are trials of the calibration study, value = verified RMSE
    study = optuna.load_study(study_name=result.study, storage=result.storage)
    values = [t.value for t in study.trials]
    assert min(values) == pytest.approx(result.rmse_n)
    assert study.user_attrs["result"]["params"] == result.params


@pytest.mark.slow
def test_the_right_effect_recovers_its_parameter(tmp_path):
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    tests = [
        {"test_id": "t0a", "tension_n": 0.0},
        {"test_id": "t0b", "tension_n": 0.0},
        {"test_id": "t20", "tension_n": 20.0},
        {"test_id": "t40", "tension_n": 40.0},
    ]
    base = surrogate.calibrate(_study(tmp_path, tests, hidden=hidden), progress=False)
    assert base.rmse_n > 5 * base.noise_n  # the base model cannot follow the tension
    path = _study(tmp_path, tests, hidden=hidden)
    result = surrogate.calibrate(path, effects=["tension"], progress=False)
    truth = {**TRUTH, "tension.k_e": 0.006, "tension.k_s": 0.006}
    at_truth = surrogate.compare(
        path, params=truth, effects=["tension"], plots=False, progress=False
    ).rmse_n
    assert result.rmse_n <= 1.03 * at_truth
    # stated tolerance: kE and kS within 10 % of the truth
    assert result.params["tension.k_e"] == pytest.approx(0.006, rel=0.10)
    assert result.params["tension.k_s"] == pytest.approx(0.006, rel=0.10)
    assert result.study.endswith("/calibrate/tension")
    # the hand-off: LS-DYNA's card has no tension, so the coat is named at 40 N
    card = surrogate.export(path, effects=["tension"], at={"tension_n": 40.0})
    p = result.params
    assert card.source == "calibration" and card.not_carried == []
    assert card.parameters["ECOAT"] == pytest.approx(
        1e3 * p["ecoat_gpa"] * (1 + 40 * p["tension.k_e"])
    )
    assert card.parameters["SCOAT"] == pytest.approx(
        1e3 * p["scoat_gpa"] * (1 + 40 * p["tension.k_s"])
    )


@pytest.mark.slow
def test_cli_calibrate_json_then_compare(tmp_path, capsys):
    path = _study(tmp_path, BASE_TESTS[:2] + BASE_TESTS[2:3], budget=40)
    assert main(["calibrate", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"params", "rmse_n", "noise_n", "solver_calls", "effects"} <= set(out)
    assert set(out["params"]) == {"ecoat_gpa", "scoat_gpa", "tcoat_mm"}
    assert isinstance(out["solver_calls"], int) and out["solver_calls"] <= 40
    assert out["effects"] == []

    assert main(["compare", str(path), "--json", "--output", str(tmp_path / "plots")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["params"] == out["params"]  # the stored calibration
    assert report["rmse_n"] == pytest.approx(out["rmse_n"], rel=1e-9)
    assert [t["test_id"] for t in report["tests"]] == ["a1", "a2", "b1"]
    assert {b["band"] for b in report["bands"]} <= {"elastic rise", "transition", "plateau"}
    assert sum(b["points"] for b in report["bands"]) == 3 * 91
    assert len(report["plots"]) == 3
    for png in report["plots"]:
        assert open(png, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    # the same figures are attached to the calibration study for optuna-dashboard
    study = optuna.load_study(study_name=out["study"], storage=out["storage"])
    attrs = json.dumps(study._storage.get_study_system_attrs(study._study_id))
    for figure in ("compare-curves", "compare-residual-angle", "compare-residual-covariates"):
        assert figure in attrs


def test_the_points_elsewhere_stay_within_the_budget(tmp_path, monkeypatch):
    """The surrogate's best points elsewhere (for the profiles) are verifications like any
    other: with one left, one is run, not all of them (three had been run, 42 solver calls
    of a budget of 40, on a calibration whose trajectory left one verification there)."""
    from surrogate.calibration._basins import Start
    from surrogate.calibration._loop import CalibrationLoop
    from surrogate.gp import CurveSurrogate

    path = _study(tmp_path, BASE_TESTS[:2] + BASE_TESTS[2:3], budget=200)
    _, loop = run_calibration(path, progress=False, record=False, intervals=False)
    assert loop is not None and loop.converged_at_best()
    problem = loop.problem
    loop.budget = loop.calibration_calls + problem.runs_per_point  # one verification left
    space = problem.space
    starts = [
        Start(space.from_unit(np.full((1, len(space)), u))[0], "a test's start")
        for u in (0.2, 0.5, 0.8)
    ]
    monkeypatch.setattr(CalibrationLoop, "_regions", lambda self, model, trials: starts)
    model = CurveSurrogate(problem.features, len(problem.groups), seed=1)
    loop._fit(model)
    found = loop._elsewhere(model, 100)
    assert len(found) == 1 and loop.calibration_calls == loop.budget


@pytest.mark.slow
def test_compare_shows_where_the_base_model_fails(tmp_path):
    hidden = {"tension": {"k_e": 0.01, "k_s": 0.01}}
    tests = [
        {"test_id": "t0", "tension_n": 0.0, "temperature_c": 22.0},
        {"test_id": "t20", "tension_n": 20.0, "temperature_c": 21.0},
        {"test_id": "t40", "tension_n": 40.0, "temperature_c": 22.5},
    ]
    path = _study(tmp_path, tests, hidden=hidden, noise=NOISE)
    # the truth's coating, no tension effect: the residual grows with the tension
    report = surrogate.compare(path, params=TRUTH, plots=False, progress=False)
    bias = {t["test_id"]: t["bias_n"] for t in report.tests}
    assert abs(bias["t0"]) < 3 * NOISE
    assert 0 < bias["t20"] < bias["t40"]
    assert report.covariates["tension_n"] > 0.95
    assert report.rmse_over_noise > 5


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--effect", "no_such_effect"], "unknown effect 'no_such_effect'"),
        (["--plugin", "no_such_module_xyz"], "cannot import plug-in module"),
        (["--budget", "0"], "--budget must be a whole number ≥ 1 of solver runs, got 0"),
        # what the calibration needs is its loop's: 3 parameters at 1 group, 8 + 1 runs
        (["--budget", "8"], "--budget 8 is too small for this calibration: it needs at least 9"),
        (["--jobs", "0"], "--jobs must be ≥ 1"),
    ],
)
def test_bad_calibrate_options_are_one_line_errors(tmp_path, capsys, args, message):
    path = _study(tmp_path, BASE_TESTS[:2])
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", str(path), *args])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no storage, no cache


BAD_FILES = {
    "missing column": "test_id,angle_deg\na,0\na,1\na,2\n",
    "nan force": "test_id,angle_deg,force_n\na,0,0\na,1,nan\na,2,1\n",
    "negative force": "test_id,angle_deg,force_n\na,0,0\na,1,-1\na,2,1\n",
    "duplicate angle": "test_id,angle_deg,force_n\na,0,0\na,1,1\na,1,1\n",
    "unsorted": "test_id,angle_deg,force_n\na,0,0\na,2,1\na,1,1\n",
    "unitless": "test_id,angle_deg,force_n,tension\na,0,0,1\na,1,1,1\na,2,1,1\n",
    "direction": "test_id,angle_deg,force_n,direction\na,0,0,up\na,1,1,up\na,2,1,up\n",
    "beyond the rig's range": "test_id,angle_deg,force_n\na,0,0\na,45,1\na,120,1\n",
}


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"jobs": 0}, "--jobs must be ≥ 1, got 0"),
        ({"max_solver_calls": 0}, "--budget must be a whole number ≥ 1 of solver runs, got 0"),
        (
            {"max_solver_calls": 5},
            "--budget 5 is too small for this calibration: it needs at least 9 solver runs (an "
            "initial design of 8 and one verification: a run at the one condition group); "
            "raise it",
        ),
    ],
)
def test_the_api_refuses_what_the_cli_refuses_before_writing(tmp_path, options, message):
    path = _study(tmp_path, BASE_TESTS[:2])
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(surrogate.InputDataError) as error:
        surrogate.calibrate(path, progress=False, **options)
    assert str(error.value) == message
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no storage, no cache


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_measurement_files_are_refused_by_calibrate_and_compare(tmp_path, capsys, case):
    path = _study(tmp_path, BASE_TESTS[:2])
    (tmp_path / "tests.csv").write_text(BAD_FILES[case])
    text = path.read_text().replace("[measurements]", "[measurements]\nnoise_n = 0.05")
    path.write_text(text)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for command in ("calibrate", "compare"):
        with pytest.raises(SystemExit) as exit_info:
            main([command, str(path)])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("surrogate: error:") and "\n" not in err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_no_replicates_and_no_stated_noise_is_refused(tmp_path):
    path = _study(tmp_path, BASE_TESTS[::2])  # one test per condition
    with pytest.raises(surrogate.InputDataError, match="noise_n"):
        surrogate.calibrate(path, progress=False)


def test_compare_refuses_params_outside_the_ranges_or_incomplete(tmp_path):
    path = _study(tmp_path, BASE_TESTS[:2])
    with pytest.raises(surrogate.InputDataError, match="outside its range"):
        surrogate.compare(path, params={**TRUTH, "ecoat_gpa": 40.0}, plots=False)
    with pytest.raises(surrogate.InputDataError, match="missing tcoat_mm"):
        surrogate.compare(path, params={"ecoat_gpa": 1.0, "scoat_gpa": 0.1}, plots=False)
    with pytest.raises(surrogate.InputDataError, match="no calibration"):
        surrogate.compare(path, plots=False)


def test_model_state_surrogate_inputs_follow_the_effects(tmp_path):
    """The surrogate sees what the solver sees: a tension effect is a stiffer coat."""
    from surrogate.calibration._problem import CalibrationProblem
    from surrogate.solvers import state_features
    from surrogate.study._measurements import load_measurements
    from surrogate.study._spec import load_study

    path = _study(tmp_path, BASE_TESTS)
    spec = load_study(path)
    problem = CalibrationProblem(spec, load_measurements(spec.measurements_file), ["tension"])
    assert problem.conditions == ("tension_n",)  # temperature is no condition
    assert len(problem.groups) == 2  # replicates share a run
    theta = np.array([1.0, 0.1, 0.02, 0.01, 0.0])
    at0, at20 = (state_features(problem.state(theta, g)) for g in (0, 1))
    assert at20[0] - at0[0] == pytest.approx(np.log(1 + 0.01 * 20.0))  # log D grows
    assert at20[1] == pytest.approx(at0[1])  # k_s = 0: the plastic moment does not


def test_the_fast_mean_of_the_curve_surrogate_is_scikit_learns(tmp_path):
    from surrogate.calibration._loop import SolverRuns
    from surrogate.calibration._problem import CalibrationProblem
    from surrogate.gp import CurveSurrogate
    from surrogate.study._measurements import load_measurements
    from surrogate.study._spec import load_study

    spec = load_study(_study(tmp_path, BASE_TESTS))
    problem = CalibrationProblem(spec, load_measurements(spec.measurements_file), ["tension"])
    runs = SolverRuns(problem, tmp_path / "cache", jobs=1)
    X = problem.space.from_unit(np.random.default_rng(0).random((10, len(problem.space))))
    runs.run(X, [i % 2 for i in range(10)])
    model = CurveSurrogate(problem.features, len(problem.groups)).fit(
        np.array(runs.X), np.array(runs.groups), np.array(runs.curves)
    )
    fast = model.predict(X[:3])
    slow, std = model.predict(X[:3], return_std=True)  # through GaussianProcessRegressor.predict
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-12)
    assert fast.shape == (3, 2, 91) and np.all(std >= 0)
    # at a training point the surrogate reproduces the solver's curve
    at = model.predict(np.array(runs.X[:1]))[0, runs.groups[0]]
    np.testing.assert_allclose(at, runs.curves[0], rtol=2e-3, atol=2e-3)


def test_the_shipped_measurements_are_what_the_seeded_script_makes(tmp_path):
    import importlib.util

    from tests.conftest import REPO

    spec = importlib.util.spec_from_file_location("make", REPO / "scripts/make_measurements.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(tmp_path)
    shipped = REPO / "data/measurements/webbing_tests.csv"
    assert (tmp_path / "data/measurements/webbing_tests.csv").read_bytes() == shipped.read_bytes()
    truth = json.loads((REPO / "tests/data/webbing_tests_truth.json").read_text())
    assert truth["hidden_effects"] == module.HIDDEN
    # the product never reads the truth: no module of the package names the file
    for source in (REPO / "surrogate").rglob("*.py"):
        assert "webbing_tests_truth" not in source.read_text()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_surrogate_search_finds_the_surrogates_best_and_chunks_change_nothing(
    tmp_path, monkeypatch, seed
):
    """The global phase's search of the surrogate (a Sobol batch, then L-BFGS-B from its
    best points): its candidate predicts no worse than any of 4096 random points, and
    predicting the batch in chunks picks the same candidate."""
    import surrogate.calibration._loop as loop_module
    from surrogate.calibration._loop import CalibrationLoop, SolverRuns
    from surrogate.calibration._problem import CalibrationProblem
    from surrogate.gp import CurveSurrogate
    from surrogate.study._measurements import load_measurements
    from surrogate.study._spec import load_study

    spec = load_study(_study(tmp_path, BASE_TESTS))
    problem = CalibrationProblem(spec, load_measurements(spec.measurements_file), [])
    runs = SolverRuns(problem, tmp_path / "cache", jobs=1)
    rng = np.random.default_rng(seed)
    X = problem.space.from_unit(rng.random((12, len(problem.space))))
    runs.run(X, [i % len(problem.groups) for i in range(12)])
    model = CurveSurrogate(problem.features, len(problem.groups)).fit(
        np.array(runs.X), np.array(runs.groups), np.array(runs.curves)
    )
    loop = CalibrationLoop(problem, runs, noise=0.05, budget=100, progress=False, label="t")
    theta, predicted = loop._search(model, 300)
    assert problem.space.clip(theta[None, :])[0] == pytest.approx(theta, rel=0, abs=0)
    assert predicted == pytest.approx(problem.batch_rmse(model.predict(theta[None, :]))[0])
    randoms = problem.space.from_unit(rng.random((4096, len(problem.space))))
    others = problem.batch_rmse(model.predict(randoms))
    assert predicted <= others.min()
    monkeypatch.setattr(loop_module, "_CHUNK", 100)  # 512 points in six chunks
    again, predicted_again = loop._search(model, 300)
    np.testing.assert_array_equal(again, theta)
    assert predicted_again == predicted


@pytest.mark.slow
def test_a_budget_below_the_design_refuses_a_calibration_not_a_diagnosis_recalibration(tmp_path):
    """Three parameters at two condition groups need 8 + 2 runs, with ``tension`` 12 + 2:
    a budget of 10 is refused for the calibration a user asks for (before any run, where
    it used to overshoot it); a diagnosis's recalibration of that candidate, which is
    not recorded, gets its initial design and one verification, as the model it is
    ranked against had."""
    path = _study(tmp_path, BASE_TESTS, budget=10)
    with pytest.raises(InputDataError, match="needs at least 14 solver runs"):
        surrogate.calibrate(path, effects=["tension"], progress=False)
    found, loop = run_calibration(path, effects=["tension"], progress=False, record=False)
    assert loop.budget == 14
    assert 14 - 2 < found.solver_calls <= 14  # the design and at most one verification


def test_compare_records_its_figures_in_a_journal_storage(tmp_path):
    """compare opened its storage URL with SQLAlchemy directly: a journal (a ``.log``
    path) failed after the work with "Could not parse SQLAlchemy URL"."""
    path = _study(tmp_path, BASE_TESTS[:2])
    journal = tmp_path / "studies.log"
    found = surrogate.compare(path, params=TRUTH, plots=False, progress=False, storage=str(journal))
    study = optuna.load_study(study_name=found.study, storage=open_storage(str(journal)))
    assert study.study_name.endswith("/calibrate/base")
