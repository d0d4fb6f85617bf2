"""Multi-fidelity: the built-in solver as the fast prior of an external full solver.

The "expensive" solver here is tests/fidelity.py's: the built-in solver with a known
smooth distortion (the size of CalculiX's coarse mesh's difference), so the correction
has a known target and every expensive run is counted. CalculiX itself runs in
tests/solvers/test_calculix_run.py.
"""

from __future__ import annotations

import json
import logging
import os
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import surrogate
from surrogate.calibration._problem import coat_section
from surrogate.calibration._synthetic import synthetic_measurements
from surrogate.study._conditions import CONDITIONS
from tests.fidelity import LOG_VARIABLE, distortion
from tests.studies import write_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def _expensive_log(folder: Path) -> list[list[str]]:
    """The expensive runs so far, each as [input hash, process id]."""
    log = folder / "expensive.log"
    return [line.split() for line in log.read_text().splitlines()] if log.exists() else []


def _expensive_runs(folder: Path) -> int:
    return len(_expensive_log(folder))


def _paper_study(folder: Path, solver: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = (STUDIES / "paper_coating.toml").read_text()
    text = text.replace('name = "paper-coating"', 'name = "mf"')
    text = text.replace('kind = "builtin"', f'kind = "test-distorted"\n{solver}')
    text = text.replace("surrogate_trials = 300", "surrogate_trials = 100")
    path = folder / "mf.toml"
    path.write_text(text)
    return path


@pytest.fixture
def log_runs(tmp_path, monkeypatch):
    monkeypatch.setenv(LOG_VARIABLE, str(tmp_path / "expensive.log"))
    return tmp_path


# -- the main job ---------------------------------------------------------------------------------
TARGETS = (9.958, 48.3, 11.462)  # benchmarks/identification.py's three targets


@pytest.mark.parametrize("target", TARGETS)
def test_run_verifies_in_few_expensive_runs_and_reports_the_correction(
    distorted_solver, log_runs, target
):
    path = _paper_study(log_runs / "mf", "")
    result = surrogate.run(path, target=target, progress=False)
    assert result.status == "verified", result.message
    # every expensive run is counted, none after verification (the corrected model gives
    # the identifiability exponents), the built-in runs apart
    assert result.solver_calls == result.calls_to_verify == _expensive_runs(log_runs)
    assert result.calls_to_verify <= 3
    mf = result.multi_fidelity
    assert mf["dropped"] is None and mf["low_fidelity_runs"] > 100
    assert result.identifiability["exponents_from"] == "corrected model"
    # the verified point meets the target on the expensive solver itself
    v = result.verified
    coat = {k: v[k] for k in ("ecoat_gpa", "scoat_gpa", "tcoat_mm")}
    expensive = surrogate.simulate(**coat, solver="test-distorted")
    assert abs(expensive.f60_n / target - 1) <= 0.01 and expensive.theta_sat_deg >= 80
    # the correction reported at the answer is the known distortion there
    builtin = surrogate.simulate(**coat)
    settings = {"offset": -0.03, "slope": 0.01, "bend": 0.02, "rough": 0.0}
    inputs = surrogate.solvers.solver_inputs(coat, surrogate.Rig())
    factor = distortion(inputs, np.array([60.0]), settings)[0]
    assert mf["correction"]["f60_percent"] == pytest.approx(100 * (factor - 1), abs=1e-6)
    assert builtin.f60_n * factor == pytest.approx(expensive.f60_n, rel=1e-9)
    assert "Multi-fidelity: the searched model was the built-in solver corrected" in result.message
    assert "F60 " in result.message and "curve RMSE" in result.message


def test_the_prior_saves_expensive_runs_against_the_single_fidelity_loop(
    distorted_solver, log_runs, monkeypatch
):
    """Side by side on the same target and seed: the corrected model verifies in fewer
    expensive runs than the loop that starts from a Latin hypercube on the expensive
    solver (five runs before its first surrogate)."""
    calls = {}
    for name, key in (("multi", ""), ("single", "multi_fidelity = false")):
        path = _paper_study(log_runs / name, key)
        result = surrogate.run(path, progress=False)
        assert result.status == "verified"
        calls[name] = result.calls_to_verify
        assert (result.multi_fidelity is None) == (name == "single")
    assert calls["multi"] < calls["single"]
    assert calls["single"] >= 6


def test_a_corrected_search_with_nothing_new_to_verify_ends_stalled(
    distorted_solver, log_runs, monkeypatch
):
    """The corrected search stops with runs left where it proposes no point it has not
    verified (scripted after its first proposal, the target out of reach): ``stalled``,
    the correction still trusted, the expensive runs counted."""
    import surrogate.identify._loop as loop

    real, proposed = loop._propose, []

    def once(*args, **kwargs):
        proposed.append(1)
        return real(*args, **kwargs) if len(proposed) == 1 else np.empty((0, 3))

    monkeypatch.setattr(loop, "_propose", once)
    path = _paper_study(log_runs / "mf", "")
    result = surrogate.run(path, target=500.0, progress=False)
    assert result.status == "stalled", result.message
    assert result.multi_fidelity["dropped"] is None
    assert result.solver_calls == _expensive_runs(log_runs) < 30
    assert f"stalled after {result.solver_calls} of 30 runs" in result.message


def test_a_correction_too_large_is_dropped_and_the_single_fidelity_loop_verifies(
    distorted_solver, log_runs
):
    path = _paper_study(log_runs / "mf", "offset = 0.5   # +50 %: no longer a model of it")
    result = surrogate.run(path, progress=False)
    mf = result.multi_fidelity
    assert mf["dropped"] is not None and "more than the 25 %" in mf["dropped"]
    assert mf["dropped_after"] == 1
    assert "the single-fidelity loop took over" in result.message
    assert result.status == "verified"
    assert result.identifiability["exponents_from"] == "full solver"
    assert result.solver_calls == _expensive_runs(log_runs)


def test_a_main_job_budget_below_todays_design_is_the_corrected_loops(distorted_solver, log_runs):
    """The corrected model answers first, so ``--budget 2`` is spent on it (today's loop
    refuses it: its design is 5 runs on the expensive solver); where the correction is
    dropped after its first run, today's design runs as far as the budget goes."""
    path = _paper_study(log_runs / "mf", "")
    result = surrogate.run(path, budget=2, progress=False)
    assert result.solver_calls == _expensive_runs(log_runs) <= 2
    assert result.status in {"verified", "budget_exhausted"}, result.message

    single = _paper_study(log_runs / "single", "multi_fidelity = false")
    with pytest.raises(surrogate.InputDataError, match=r"--budget \(2\) must be ≥ budget.initial"):
        surrogate.run(single, budget=2, progress=False)

    dropped = _paper_study(log_runs / "dropped", "offset = 0.5   # +50 %: no longer a model")
    runs = _expensive_runs(log_runs)
    result = surrogate.run(dropped, budget=3, progress=False)
    assert result.multi_fidelity["dropped_after"] == 1
    assert result.solver_calls == _expensive_runs(log_runs) - runs == 3  # 1 + the design's first 2
    assert "the single-fidelity loop took over" in result.message


def test_the_batch_that_meets_the_target_is_not_judged_for_irregularity(
    distorted_solver, log_runs, monkeypatch
):
    """A drop of the correction starts today's design on the expensive solver (5 runs), so
    the batch whose run met the target is not judged: every judged prediction is recorded
    (none a miss here), and the run that verified is not among them."""
    import surrogate.identify._loop as loop

    judged = []

    class Recording(loop.MissCounter):
        def judge(self, error, sd, tolerance):
            judged.append(error)
            return False

    monkeypatch.setattr(loop, "MissCounter", Recording)
    result = surrogate.run(_paper_study(log_runs / "mf", ""), progress=False)
    assert result.status == "verified" and result.multi_fidelity["dropped"] is None
    assert len(judged) == result.calls_to_verify - 1  # one candidate a batch, all but the last


@pytest.mark.slow
def test_an_irregular_correction_is_dropped(distorted_solver, log_runs):
    """A ripple in D far shorter than the correction's length scale (±8 %): on every seed
    the corrected model either verifies within its first runs or drops the correction
    for irregularity — it never goes on burning expensive runs on a model it cannot
    trust (the single-fidelity loop then goes on; here its budget stops it at once)."""
    outcomes = []
    for seed in range(4):
        folder = log_runs / f"seed{seed}"
        path = _paper_study(folder, "rough = 0.08")
        path.write_text(path.read_text().replace("max_solver_calls = 30", "max_solver_calls = 6"))
        result = surrogate.run(path, seed=seed, progress=False)
        mf = result.multi_fidelity
        if mf["dropped"] is None:
            assert result.status == "verified" and result.calls_to_verify <= 4
        else:
            assert "too irregular for its GP" in mf["dropped"]
            assert mf["dropped_after"] <= 5
        outcomes.append(mf["dropped"] is not None)
    assert any(outcomes)  # the rule fired


def test_run_json_has_the_multi_fidelity_record(distorted_solver, log_runs, capsys):
    from surrogate._cli import main

    path = _paper_study(log_runs / "mf", "")
    assert main(["run", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["multi_fidelity"]) == {
        "low_fidelity",
        "low_fidelity_runs",
        "correction",
        "dropped",
        "dropped_after",
    }
    assert set(out["multi_fidelity"]["correction"]) == {
        "f60_percent",
        "theta_sat_deg",
        "curve_rmse_n",
        "curve_rmse_relative",
    }


# -- calibration and diagnosis ---------------------------------------------------------------------
def _calibration_study(
    folder: Path, tests, truth, *, hidden=None, seed=0, noise=0.05, settings=""
) -> Path:
    """Curves the expensive solver made at a known coating, with noise; the study (which
    states the noise level where the tests have no replicates)."""
    conditions = [tuple(sorted((k, v) for k, v in t.items() if k in CONDITIONS)) for t in tests]
    replicates = len(set(conditions)) < len(conditions)
    table = synthetic_measurements(
        tests,
        coating=truth,
        effects=hidden,
        noise_n=noise,
        seed=seed,
        solver="test-distorted",
        solver_settings=dict(tomllib.loads(settings)),
    )
    return write_study(
        folder,
        table,
        f"""
        [study]
        name = "mf"
        seed = {seed}
        [solver]
        kind = "test-distorted"
        {settings}
        [measurements]
        file = "tests.csv"
        {"" if replicates else f"noise_n = {noise}"}
        [budget]
        surrogate_trials = 100
        calibration_solver_calls = 30
        """,
    )


def _truth_rmse(path: Path, truth, settings=None) -> float:
    """The RMSE of the truth itself on the expensive solver: the noise floor."""
    from surrogate.calibration._problem import CalibrationProblem, load_calibration

    spec, data, _, _ = load_calibration(path, None, ())
    problem = CalibrationProblem(spec, data, ())
    curves = [
        surrogate.simulate(
            **truth, conditions=group, solver="test-distorted", solver_settings=settings
        )
        for group in problem.groups
    ]
    return problem.rmse(
        np.array([np.interp(problem.angle_deg, c.angle_deg, c.force_n) for c in curves])
    )


BENDING = [
    {"test_id": "l10", "bending_length_mm": 10.0},
    {"test_id": "l15", "bending_length_mm": 15.0},
]
TRUTHS = [  # the calibration benchmark's coatings: mid, thin-soft, early-yield
    {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
    {"ecoat_gpa": 0.6, "scoat_gpa": 0.06, "tcoat_mm": 0.012},
    {"ecoat_gpa": 3.0, "scoat_gpa": 0.07, "tcoat_mm": 0.05},
]


THICK = {"thick": 0.15}  # +15 % towards 90° per e-fold of Tcoat at fixed D and Mp


@pytest.mark.slow
@pytest.mark.parametrize("case", range(len(TRUTHS)))
def test_calibration_reaches_the_expensive_solvers_noise_floor_in_few_expensive_runs(
    distorted_solver, log_runs, case, caplog
):
    """Two bending lengths, noise 0.05 N, curves from the expensive solver: the noise
    floor (RMSE ≤ 1.05 × the truth's own, D and Mp within 5 %), ``converged`` at an
    expensive-verified point, in at most 30 expensive runs (design.md §6).

    The expensive curves also change shape with Tcoat at fixed D and Mp (``thick``),
    which the built-in ones hardly do — as CalculiX's coarse mesh against the rod: the
    correction learns it, and the expensive curves' Tcoat (within 20 %) is found.

    An expensive run takes minutes (a CalculiX diagnosis's confirmation said nothing for
    half an hour between two rounds of its local phase): each is told as it ends, with
    its step's count and time; the built-in solver's hundreds of runs are not."""
    truth = TRUTHS[case]
    settings = " ".join(f"{k} = {v}" for k, v in THICK.items())
    path = _calibration_study(log_runs / "cal", BENDING, truth, seed=case, settings=settings)
    floor = _truth_rmse(path, truth, THICK)
    before = _expensive_runs(log_runs)
    caplog.set_level(logging.INFO, logger="surrogate")
    result = surrogate.calibrate(path, progress=True)
    assert result.status == "converged" and result.misfit == "within the noise", result.message
    assert result.rmse_n <= 1.05 * floor
    told = [r.getMessage() for r in caplog.records if " of this step " in r.getMessage()]
    assert len(told) == _spent(result) == _expensive_runs(log_runs) - before
    line = re.compile(
        r"\[mf/calibrate/base\] test-distorted run (\d+) of (\d+) of this step finished, "
        r"\d+ s into it"
    )
    counts = [line.fullmatch(text) for text in told]
    assert all(counts) and all(1 <= int(m[1]) <= int(m[2]) for m in counts if m), told
    (d, mp), (d0, mp0) = coat_section(result.params, 1.2), coat_section(truth, 1.2)
    assert abs(d / d0 - 1) <= 0.05 and abs(mp / mp0 - 1) <= 0.05
    assert abs(result.params["tcoat_mm"] / truth["tcoat_mm"] - 1) <= 0.2
    assert _spent(result) == _expensive_runs(log_runs) - before
    assert result.solver_calls <= 30
    mf = result.multi_fidelity
    assert mf["dropped"] is None and mf["low_fidelity_runs"] > result.solver_calls
    assert mf["optimum_tested_by"] == "test-distorted", result.message  # its own test held
    assert result.retried == {} and "retry" not in result.message  # every run the first
    # the reported size of the correction is the solvers' difference at the answer
    coat = {k: result.params[k] for k in ("ecoat_gpa", "scoat_gpa", "tcoat_mm")}
    ratios = [
        surrogate.simulate(
            **coat, conditions=c, solver="test-distorted", solver_settings=THICK
        ).f60_n
        / surrogate.simulate(**coat, conditions=c).f60_n
        for c in ({"bending_length_mm": 10.0}, {"bending_length_mm": 15.0})
    ]
    reported = mf["correction"]["f60_percent"]  # the group of the larger curve difference
    assert any(reported == pytest.approx(100 * (r - 1), abs=1e-6) for r in ratios)


@pytest.mark.slow
def test_a_corrected_models_optimum_is_converged_on_the_expensive_solvers_own_test(
    distorted_solver, log_runs
):
    """``converged`` at a point where the corrected model's first-order test held is
    certified by the expensive solver's own test where the budget holds its Jacobian
    (p × G runs): the corrected model's slopes are learned from a few points (CalculiX's
    *mid* seed 1: its test held 0.77 % off the truth's Mp, which fits 5.5 % better). Where
    the budget does not hold it, or in a diagnosis's calibration, ``converged`` stays the
    corrected model's, nothing is spent on a test that cannot finish, and the message
    says the intervals are the corrected model's and what would certify them."""
    from surrogate.calibration._calibrate import run_calibration

    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[0], settings="thick = 0.15")
    jacobian = 3 * len(BENDING)  # p × G
    uncertified, loop = run_calibration(path, progress=False, record=False, certify=False)
    assert uncertified.status == "converged", uncertified.message
    assert uncertified.multi_fidelity["optimum_tested_by"] == "corrected model"
    assert "is left to `surrogate calibrate`" in uncertified.message
    corrected = uncertified.solver_calls
    assert corrected == loop.calibration_calls
    # the profile ends' checks on the expensive solver: on top of the calibration's, ≤ 10
    checks = uncertified.determination["verification_solver_calls"]
    assert loop.runs.calls - corrected == checks <= 10

    short, loop = run_calibration(
        path, progress=False, record=False, max_solver_calls=corrected + jacobian - 1
    )
    assert short.status == "converged" and short.solver_calls == corrected, short.message
    assert short.multi_fidelity["optimum_tested_by"] == "corrected model"
    assert "may miss test-distorted's optimum" in short.message
    assert "raise --budget to certify it" in short.message and loop.short is not None

    before = _expensive_runs(log_runs)
    certified, loop = run_calibration(path, progress=False, record=False)
    assert certified.status == "converged", certified.message
    assert certified.multi_fidelity["optimum_tested_by"] == "test-distorted"
    assert certified.multi_fidelity["tested_along"] is None  # Tcoat matters: the whole test
    assert "may miss" not in certified.message
    assert f"test that held is test-distorted's own (a Jacobian of {jacobian}" in (
        certified.message
    )
    assert certified.solver_calls >= corrected + jacobian
    # the built-in optimum missed the expensive curves (which change with Tcoat) by more
    # than the misfit left: the basins were ranked on a model that could not tell them apart
    assert "Another basin of test-distorted's may fit better" in certified.message
    # the corrected model's runs come from the cache; the ends' checks (≤ 10) may be new
    made = _expensive_runs(log_runs) - before
    checks = certified.determination["verification_solver_calls"]
    assert certified.solver_calls - corrected <= made <= certified.solver_calls - corrected + checks
    assert certified.rmse_n <= uncertified.rmse_n
    fit = loop.best_fit()
    assert fit is not None and not loop.by_corrected_model(fit)  # the intervals' Jacobian


@pytest.mark.slow
@pytest.mark.parametrize("case", [0, 1])
def test_the_certificate_differences_the_expensive_solver_where_the_curves_depend(
    distorted_solver, log_runs, case
):
    """The default distortion leaves the curves hardly dependent on Tcoat at fixed D and
    Mp (as the built-in ones): the certificate differences the expensive solver along D
    and Mp only (2 × G runs, not 3 × G) and borrows the corrected model's slope along
    Tcoat. Where that test held, the expensive solver's whole test at the same point holds
    too (its runs are made here, outside the calibration's); a study whose curves do
    depend on Tcoat (``thick``) takes the whole test (the test above)."""
    from surrogate.calibration._calibrate import run_calibration
    from surrogate.calibration._local import ResidualModel, optimum_test

    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[case], seed=case)
    uncertified, _ = run_calibration(path, progress=False, record=False, certify=False)
    assert uncertified.multi_fidelity["optimum_tested_by"] == "corrected model"
    certified, loop = run_calibration(path, progress=False, record=False)
    assert certified.status == "converged", certified.message
    mf = certified.multi_fidelity
    assert mf["optimum_tested_by"] == "test-distorted"
    assert mf["tested_along"] == {"own": "D, Mp", "corrected": "tcoat_mm at fixed D and Mp"}
    assert certified.solver_calls == uncertified.solver_calls + 2 * len(BENDING)
    assert "test-distorted's own along D, Mp (a Jacobian of 4 test-distorted runs)" in (
        certified.message
    )
    whole = optimum_test(ResidualModel(loop.problem, loop.runs), loop.best().theta)
    assert whole.converged, whole.message
    assert "Another basin" not in certified.message  # the built-in optimum's miss was small


@pytest.mark.slow
def test_a_calibration_says_where_the_expensive_solver_finished_only_after_a_retry(
    distorted_solver, log_runs
):
    """Where the expensive solver finished the runs at the answer only after a retry (as
    ccx does with other increments, whose curves jump by a few per cent between
    neighbours), the result names the tests and why the first attempts stopped, and the
    message says a local optimum at the noise level may not be verifiable there."""
    settings = "retry_above_tcoat_mm = 0.001"  # every coat of the range
    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[0], seed=0, settings=settings)
    result = surrogate.calibrate(path, progress=False)
    assert result.retried == {
        "l10": "with fixed increments: stopped (thicker than 0.001 mm)",
        "l15": "with fixed increments: stopped (thicker than 0.001 mm)",
    }
    assert "test-distorted finished test(s) l10, l15 at this point only after a retry" in (
        result.message
    )
    assert "may not be verifiable here" in result.message
    assert result.to_json()["retried"] == result.retried


FAILING = [  # (truth, the Tcoat above which the expensive solver fails, seed)
    (0, 0.0205, 1),  # the built-in optimum (Ecoat at its bound) fails: the valley probes run
    (0, 0.0202, 0),
    (1, 0.0122, 2),  # proposals fail too: the trust region shrinks and the loop goes on
    (2, 0.0505, 1),  # a failed proposal within the box: the expensive solver's own test
]


@pytest.mark.slow
@pytest.mark.parametrize("case", FAILING)
def test_calibration_goes_on_where_the_expensive_solver_fails(distorted_solver, log_runs, case):
    """An expensive solver that stops short for coats just thicker than the truth's (as
    ccx's coarse mesh does for thick coats): the built-in valley's optimum, probes and
    proposals there fail; the calibration still reaches the noise floor, ``converged``,
    in at most 36 expensive runs — failed runs counted. (30 until the built-in solver
    ``rod-2``: since, the first case reaches the corrected model's optimum in 22 runs, where
    30 left room to start the expensive solver's own first-order test, 6 runs, but not to
    finish it — the test found a step 0.1 % lower — and ended ``budget_exhausted``; with
    36 it is certified on that test. Before, it ended in 26 runs ``converged`` on the
    corrected model's test alone, 4 runs left. The others take 30, 8 and 28 runs.)"""
    index, limit, seed = case
    truth = TRUTHS[index]
    settings = f"thick = 0.15\nfail_above_tcoat_mm = {limit}"
    path = _calibration_study(log_runs / "cal", BENDING, truth, seed=seed, settings=settings)
    text = path.read_text()
    assert "calibration_solver_calls = 30" in text
    path.write_text(text.replace("calibration_solver_calls = 30", "calibration_solver_calls = 36"))
    floor = _truth_rmse(path, truth, {"thick": 0.15, "fail_above_tcoat_mm": limit})
    before = _expensive_runs(log_runs)
    result = surrogate.calibrate(path, progress=False)
    assert result.status == "converged" and result.misfit == "within the noise", result.message
    assert result.rmse_n <= 1.05 * floor and result.params["tcoat_mm"] <= limit
    assert _spent(result) == _expensive_runs(log_runs) - before
    assert result.solver_calls <= 36
    assert result.multi_fidelity["dropped"] is None


@pytest.mark.slow
def test_where_the_expensive_solver_runs_nothing_todays_loop_tries_and_says_so(
    distorted_solver, log_runs
):
    """An expensive solver that fails for every coat of the range (above 0.005 mm): the
    corrected optimum and the probes fail, today's loop takes over on the expensive
    solver (its Latin hypercube), finds no point it can run either, and the calibration
    ends with a one-line error naming the solver's reason and the fix, within budget."""
    settings = "fail_above_tcoat_mm = 0.005"
    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[0], seed=1, settings="")
    text = path.read_text().replace(
        'kind = "test-distorted"', f'kind = "test-distorted"\n{settings}'
    )
    path.write_text(text)
    before = _expensive_runs(log_runs)
    with pytest.raises(surrogate.InputDataError) as error:
        surrogate.calibrate(path, progress=False)
    message = str(error.value)
    assert "found no parameter point the solver could run at every test" in message
    assert "a coat thicker than 0.005 mm" in message
    assert "check the parameter ranges" in message and "\n" not in message
    assert 10 < _expensive_runs(log_runs) - before <= 30  # today's loop ran after the first 10


DIAGNOSIS_TESTS = [
    {"test_id": "a1", "tension_n": 0.0, "direction": "warp", "temperature_c": 21.0},
    {"test_id": "a2", "tension_n": 0.0, "direction": "warp", "temperature_c": 24.5},
    {"test_id": "b", "tension_n": 20.0, "direction": "weft", "temperature_c": 22.0},
    {"test_id": "c", "tension_n": 40.0, "direction": "warp", "temperature_c": 23.0},
]


@pytest.mark.slow
def test_diagnosis_names_a_hidden_effect_confirming_it_on_the_expensive_solver(
    distorted_solver, log_runs, caplog
):
    """Hidden tension in curves the expensive solver made: the candidates are refitted on
    the corrected built-in model, the leader is confirmed on the expensive solver (its
    RMSE after adding it there within 1.3 × noise, its progress shown under its model's
    name), membrane_bending — which the solver cannot model — is skipped with its reason,
    and at most 60 expensive runs are spent, a verification's runs in ``jobs`` processes
    side by side."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3)
    data_runs = _expensive_runs(log_runs)
    candidates = ["tension", "anisotropy", "hardening", "membrane_bending"]
    caplog.set_level(logging.INFO, logger="surrogate")
    result = surrogate.diagnose(path, candidates=candidates, jobs=2)
    assert result.systematic
    processes = {pid for _, pid in _expensive_log(log_runs)[data_runs:]}
    assert len(processes - {str(os.getpid())}) >= 2  # child processes ran them
    confirmation = [
        r.getMessage() for r in caplog.records if "/calibrate/tension]" in r.getMessage()
    ]
    assert any("verified" in line for line in confirmation), confirmation[:5]
    leader = result.ranking[0]
    assert leader["effect"] == "tension" and leader["confirmed_by"] == "test-distorted"
    assert leader["delta_bic"] < -10 and leader["rmse_n"] <= 1.3 * result.noise_n
    # its calibration stopped at the first verified point near the noise (the rule)
    assert leader["unsettled"] is None or leader["unsettled"].startswith(
        "stopped by the diagnosis's rule: its verified"
    )
    assert result.verdict.startswith("missing effect: tension")
    mf = result.multi_fidelity
    assert mf["confirmed"] == ["tension"]
    assert [s["effect"] for s in mf["skipped"]] == ["membrane_bending"]
    assert "bare-webbing" in mf["skipped"][0]["reason"]
    assert "skipped, test-distorted cannot model them: membrane_bending" in result.verdict
    assert "membrane_bending" not in [c["effect"] for c in result.ranking]
    # issue 66: ≤ 20 expensive runs a verdict, and the verdict says what they went to
    assert result.solver_calls == _expensive_runs(log_runs) - data_runs <= 20
    spent = mf["spent"]
    assert spent["calibration"] + sum(spent["confirmations"].values()) == result.solver_calls
    assert list(spent["confirmations"]) == ["tension"]
    assert f"{result.solver_calls} test-distorted runs: {spent['calibration']} calibrating" in (
        result.verdict
    )
    assert f"{spent['confirmations']['tension']} confirming tension" in result.verdict
    assert mf["low_fidelity_runs"] > result.solver_calls
    unconfirmed = [c for c in result.ranking if c["effect"] != "tension"]
    assert all(c["confirmed_by"] is None for c in unconfirmed)


HARDENING_TESTS = [  # benchmarks/fidelity.py's hidden-hardening set: two lengths, replicates
    {"test_id": "a1", "bending_length_mm": 10.0, "temperature_c": 21.0},
    {"test_id": "a2", "bending_length_mm": 10.0, "temperature_c": 24.0},
    {"test_id": "b1", "bending_length_mm": 15.0, "temperature_c": 22.5},
    {"test_id": "b2", "bending_length_mm": 15.0, "temperature_c": 21.5},
]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 4])
def test_a_better_basin_of_the_current_model_does_not_unname_a_leader_that_beats_it(
    distorted_solver, log_runs, seed
):
    """Hidden hardening in curves the expensive solver made: the basin check finds the
    base model refitted from hardening's optimum (hardening off) 2-3 % better than its
    calibration, which with an external solver is not recalibrated here. Hardening still
    fits decisively better than that basin, so it is named and the verdict says what the
    basin took back (before: "no effect is named" on seeds 0, 1, 2 and 4 of 0-4) — in at
    most 20 expensive runs (issue 66)."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.1, "tcoat_mm": 0.02}
    hidden = {"hardening": {"ratio": 0.1}}
    path = _calibration_study(log_runs / "diag", HARDENING_TESTS, truth, hidden=hidden, seed=seed)
    data_runs = _expensive_runs(log_runs)
    result = surrogate.diagnose(path, progress=False, jobs=1)
    (entry,) = result.rebased
    assert entry["found_by"] == "hardening" and not entry["replaced"] and entry["still_named"]
    assert entry["rmse_after_n"] < entry["rmse_before_n"]
    assert entry["delta_bic_against_it"] < -10
    assert "part of the gain was the basin's" in result.verdict
    assert "missing effect: hardening" in result.verdict, result.verdict
    leader = result.ranking[0]
    assert leader["effect"] == "hardening" and leader["confirmed_by"] == "test-distorted"
    assert leader["rmse_n"] <= 1.3 * result.noise_n
    assert result.solver_calls == _expensive_runs(log_runs) - data_runs <= 20


@pytest.mark.slow
def test_a_diagnosis_after_calibrate_keeps_its_result_and_names_the_effect(
    distorted_solver, log_runs
):
    """``calibrate`` runs the current model to its end and records it; a diagnosis after it
    stops its own calibration of that model early (the rule), so that calibration fits
    worse than the recorded one. It must not replace the recorded result, and being known
    short of its best, an earlier point within the 3-fold its rule allows for is no
    "better basin" that unnames the leader."""
    import optuna

    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3)
    calibrated = surrogate.calibrate(path, progress=False)
    result = surrogate.diagnose(path, candidates=["tension", "anisotropy"], progress=False)
    assert result.multi_fidelity["spent"]["calibration_stopped"] is not None
    assert result.rmse_n > calibrated.rmse_n  # stopped short of what calibrate reached
    assert not result.rebased, result.rebased
    assert result.verdict.startswith("missing effect: tension"), result.verdict
    study = optuna.load_study(study_name=calibrated.study, storage=calibrated.storage)
    assert study.user_attrs["result"]["rmse_n"] == calibrated.rmse_n  # calibrate's stands


@pytest.mark.slow
def test_a_leader_not_decisive_against_the_early_stop_reruns_the_calibration_to_its_end(
    distorted_solver, log_runs, monkeypatch, caplog
):
    """Where the leader would not be decisive against the 3-fold lower RMSE a calibration
    stopped early may yet reach (here forced), the current model's calibration is run to
    its end (no early stop) and the candidates ranked again; ``solver_calls`` counts each
    expensive run once (the rerun's first point is a cached one), the purposes each their
    own."""
    from surrogate.calibration import _diagnose

    monkeypatch.setattr(_diagnose, "_decisive_against_lower", lambda *args: False)
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3)
    data_runs = _expensive_runs(log_runs)
    caplog.set_level(logging.INFO, logger="surrogate")
    result = surrogate.diagnose(path, candidates=["tension", "anisotropy"], jobs=1)
    said = [r.getMessage() for r in caplog.records]
    assert sum("it is run to its end and the candidates ranked again" in m for m in said) == 1
    assert result.verdict.startswith("missing effect: tension")
    spent = result.multi_fidelity["spent"]
    assert spent["calibration_stopped"] is None  # the second calibration ran to its end
    assert "stopped early" not in result.verdict
    # every expensive run counted once, though the rerun verified the first point again
    assert result.solver_calls == _expensive_runs(log_runs) - data_runs
    assert spent["calibration"] + spent["confirmations"]["tension"] > result.solver_calls
    assert "a run two of them used counted in each" in result.verdict


@pytest.mark.slow
def test_a_diagnosis_whose_calibration_dropped_the_correction_still_ranks_on_it(
    distorted_solver, log_runs
):
    """Where the current model's calibration dropped the correction (here at once: the
    expensive curves lie 50 % above the built-in ones, beyond the 25 % it is trusted
    for), the candidates are still ranked on the corrected built-in model and only the
    leaders are calibrated on the expensive solver: refitting each candidate with the
    expensive solver itself took (p + 1)·G runs an iteration (here 306 expensive runs
    against 54, the same verdict). The verdict, named only on the expensive solver's
    confirmation, and the record say the correction was dropped."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(
        log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3, settings="offset = 0.5"
    )
    data_runs = _expensive_runs(log_runs)
    result = surrogate.diagnose(path, candidates=["tension", "anisotropy"], progress=False)
    mf = result.multi_fidelity
    assert mf is not None and mf["dropped"] is not None and "25 %" in mf["dropped"]
    assert mf["dropped_after"] >= 1
    leader = result.ranking[0]
    assert leader["effect"] == "tension" and leader["confirmed_by"] == "test-distorted"
    assert mf["confirmed"] == ["tension"]
    assert result.verdict.startswith("missing effect: tension")
    assert "which the current model's calibration dropped after" in result.verdict
    assert result.ranking[1]["confirmed_by"] is None  # ranked on the corrected model only
    assert result.solver_calls == _expensive_runs(log_runs) - data_runs <= 60


@pytest.mark.slow
@pytest.mark.parametrize(
    ("settings", "hidden", "budget", "settled"),
    [
        # a rough expensive response and one verification: the confirmation cannot settle
        # (with 10 runs it reached the noise in 9 once the corrected model was solved again
        # where the inherited correction missed)
        ("rough = 0.02", {"tension": {"k_e": 0.006, "k_s": 0.006}}, 3, False),
        # hardening hidden too but not a candidate: settled, and truly unexplained. A budget
        # that holds the expensive solver's own local phase: where the corrected model's test
        # did not hold (a 2-core EPYC without AVX-512: its Jacobian not trusted at 6 runs) that
        # phase's two Jacobians (15 runs each, the second at a smaller step) and a failed step
        # (12) settled it at 48; with 10 it settled on the AVX-512 host only, 30 were spent here
        ("", {"tension": {"k_e": 0.006, "k_s": 0.006}, "hardening": {"ratio": 0.1}}, 60, True),
    ],
)
def test_a_misfit_after_a_confirmation_is_unexplained_only_where_it_settled(
    distorted_solver, log_runs, settings, hidden, budget, settled
):
    """The leader's confirmation with few expensive runs: where it stopped short of a
    verified local optimum its entry says why (``unsettled``) and the misfit it leaves
    is open, not "unexplained"; where it reached one, a misfit left is unexplained."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    path = _calibration_study(
        log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3, settings=settings
    )
    text = path.read_text().replace(
        "calibration_solver_calls = 30", f"calibration_solver_calls = {budget}"
    )
    path.write_text(text)
    result = surrogate.diagnose(path, candidates=["tension", "anisotropy"], progress=False)
    leader = result.ranking[0]
    assert leader["effect"] == "tension" and leader["confirmed_by"] == "test-distorted"
    assert result.verdict.startswith("missing effect: tension")
    assert leader["rmse_n"] > 1.3 * result.noise_n  # a misfit remains after it
    if settled:
        assert leader["unsettled"] is None
        assert result.unexplained is not None and "write a plug-in effect" in result.verdict
    else:
        assert leader["unsettled"].startswith("not at a verified local optimum")
        assert "whether another effect is missing is open" in result.verdict
        assert result.unexplained is None and "plug-in" not in result.verdict


@pytest.mark.slow
def test_a_systematic_misfit_of_the_corrected_loop_says_what_it_cannot_rule_out(
    distorted_solver, log_runs
):
    """Curves with a hidden tension calibrated without it: the misfit is systematic, and
    the corrected loop — whose global search ran before the expensive runs taught it —
    says the misfit may also be a basin of the expensive solver's, and what would tell
    (on CalculiX-made curves of a mid coating it converged at 3.3 × the truth's RMSE in
    such a basin: README)."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3)
    result = surrogate.calibrate(path, progress=False)
    assert result.status == "converged" and result.misfit == "systematic", result.message
    assert "may also be a basin of test-distorted's" in result.message
    assert "`[solver] multi_fidelity = false`" in result.message


def test_a_resumed_or_worker_run_repeats_no_expensive_run(distorted_solver, log_runs):
    """The corrected model's decisions follow from the expensive runs alone, so a run
    started again on the same storage solves nothing more, and two local worker
    processes on a journal storage verify the same points as one process."""
    path = _paper_study(log_runs / "mf", "")
    first = surrogate.run(path, progress=False)
    runs = _expensive_runs(log_runs)
    again = surrogate.run(path, progress=False)
    assert _expensive_runs(log_runs) == runs and again.verified == first.verified
    assert again.solver_calls == first.solver_calls

    other = _paper_study(log_runs / "workers", "")
    journal = f"journal://{log_runs / 'workers' / 'mf.journal'}"
    parallel = surrogate.run(other, storage=journal, jobs=2, progress=False)
    assert parallel.verified == first.verified
    assert parallel.solver_calls == first.solver_calls
    assert _expensive_runs(log_runs) == runs + first.solver_calls


def test_the_trust_region_follows_the_verified_over_predicted_decrease():
    """The ratio test of the corrected model's proposals (Alexandrov et al. 1998): a
    proposal that verified less than a quarter of its predicted decrease — or that the
    expensive solver could not run — shrinks the region to a quarter of its step; one
    that verified more than three quarters at the region's edge doubles it, up to the
    whole range; in between, or short of the edge, it stays. A region shrunk below the
    first-order test's smallest step stalls the loop: the expensive solver's own test is
    to decide; so do two verified proposals in a row that each gained under two units of
    χ² (0.56 % of the RMSE at 182 points and 3 parameters) — a crawl the data barely
    resolve."""
    from types import SimpleNamespace

    from surrogate.calibration._fidelity import MIN_RADIUS, CorrectedCalibration
    from surrogate.calibration._loop import VerifiedPoint

    loop = CorrectedCalibration.__new__(CorrectedCalibration)  # the rule alone
    loop.progress, loop.label, loop.dropped, loop.crawled = False, "rule", None, 0
    loop.problem = SimpleNamespace(n_points=182, space=range(3))

    def after(radius, before, predicted, step, verified):
        """The radius after a proposal from RMSE ``before`` predicted at ``predicted``,
        ``step`` long, verified at ``verified`` (None: the expensive solver failed)."""
        loop.radius, loop._proposal, loop.stalled = radius, (before, predicted, step), None
        point = VerifiedPoint(np.zeros(3), verified or 0.0, {}, None, [], np.zeros(0), 0, "")
        loop.verified = [point]
        loop._manage_radius(verified is not None)
        return loop.radius

    assert after(1.0, 0.10, 0.06, 0.2, None) == pytest.approx(0.05)  # failed: ρ = −∞
    assert after(1.0, 0.10, 0.06, 0.2, 0.11) == pytest.approx(0.05)  # worse: ρ < 0
    assert after(1.0, 0.10, 0.06, 0.2, 0.095) == pytest.approx(0.05)  # ρ = 0.125
    assert after(0.2, 0.10, 0.06, 0.2, 0.09) == pytest.approx(0.2)  # ρ = 0.25 … 0.75: kept
    assert after(0.2, 0.10, 0.06, 0.2, 0.065) == pytest.approx(0.4)  # ρ > 0.75 at the edge
    assert after(0.2, 0.10, 0.06, 0.05, 0.065) == pytest.approx(0.2)  # … inside: kept
    assert after(0.8, 0.10, 0.06, 0.8, 0.06) == pytest.approx(1.0)  # at most the whole range
    assert after(0.01, 0.10, 0.06, 0.01, 0.11) == pytest.approx(0.0025)  # within the box too
    assert loop.stalled is None
    # below the test's smallest step (1/64 of ±5 % of a range): stalled, failed or worse
    for verified in (0.11, None):
        assert after(0.003, 0.10, 0.06, 0.003, verified) < MIN_RADIUS
        assert loop.stalled is not None and "smallest step" in loop.stalled
    assert after(0.003, 0.10, 0.06, 0.003, 0.07) == pytest.approx(0.003) and not loop.stalled
    # a crawl: 0.2 % and 0.2 % (ρ = 0.5 each) stall; a 5 % gain or a failure between resets
    assert after(1.0, 0.1, 0.0996, 0.2, 0.0998) == 1.0 and not loop.stalled
    assert after(1.0, 0.0998, 0.0994, 0.2, 0.0996) == 1.0
    assert loop.stalled is not None and "2 verified proposals in a row" in loop.stalled
    for between in (0.095, None):
        loop.crawled = 0
        after(1.0, 0.1, 0.0996, 0.2, 0.0998)
        after(1.0, 0.1, 0.09, 0.2, between)
        after(1.0, 0.1, 0.0996, 0.2, 0.0998)
        assert not loop.stalled, between
    loop.crawled = 0
    after(1.0, 0.1, 0.0996, 0.2, 0.0998)
    after(1.0, 0.0998, 0.0994, 0.2, 0.0989)  # 0.9 % ≥ 0.56 %: resolved, no crawl
    assert not loop.stalled
    loop.dropped = "too large"  # a dropped correction: no more proposals, nothing to manage
    assert after(0.8, 0.10, 0.06, 0.8, None) == pytest.approx(0.8)


def test_a_proposal_is_no_worse_on_the_corrected_model_than_the_first_order_tests_point(
    distorted_solver, log_runs, monkeypatch
):
    """Where the corrected model's first-order test at the best verified point found a
    better point within the trust region, the proposal the expensive solver verifies
    next is at least as good on the corrected model: ``least_squares`` from the best
    point alone had stopped short of it (CalculiX's *paper* curves: a step of 0.001
    promising 1.1 % where the test's step gave 4.2 %). On this solver the early-yield
    coating is the one of the three truths where it stops short without the rule (by
    3e-7 of the RMSE: a test of the rule, not of its size)."""
    from surrogate.calibration._fidelity import CorrectedCalibration, _step
    from surrogate.calibration._local import ResidualModel

    tests, compared = [], []
    test, propose = CorrectedCalibration._test, CorrectedCalibration._next

    def spy_test(self, model, point):
        tests.append((test(self, model, point), point))
        return tests[-1][0]

    def spy_next(self):
        tests.clear()
        proposal = propose(self)
        if proposal is None or not tests or tests[-1][0].better is None:
            return proposal
        at, best = tests[-1]
        model = ResidualModel(self.problem, self.corrected_runs(self.correction))
        if _step(model, at.better, best) <= self.radius:
            rmse = [
                float(np.sqrt(np.mean(model.residual(model.pin(theta)) ** 2)))
                for theta in (proposal, at.better)
            ]
            compared.append(rmse)
        return proposal

    monkeypatch.setattr(CorrectedCalibration, "_test", spy_test)
    monkeypatch.setattr(CorrectedCalibration, "_next", spy_next)
    settings = " ".join(f"{k} = {v}" for k, v in THICK.items())
    early_yield = 2
    path = _calibration_study(
        log_runs / "cal", BENDING, TRUTHS[early_yield], seed=early_yield, settings=settings
    )
    surrogate.calibrate(path, progress=False)
    assert compared, "no proposal followed a failed test with a better point in the region"
    for proposal, better in compared:
        assert proposal <= better * (1.0 + 1e-9)


@pytest.mark.slow
def test_a_stalled_trust_region_teaches_the_correction_the_expensive_tests_runs(
    distorted_solver, log_runs, monkeypatch
):
    """Where the corrected model's trust region stalls, the expensive solver's own
    first-order test runs at the best verified point (its Jacobian, its Gauss–Newton
    step), every one of its runs teaches the correction, and where the step verified a
    better point whose misfit the noise does not explain, the corrected model takes
    over again from there (its test, its proposals: built-in runs, a run a condition
    group to verify) instead of the expensive local phase's next round (p + 1 runs a
    group or more). On CalculiX's *paper* curves, seed 1, those rounds went 0.114 →
    0.063 → 0.056 → 0.054 N, 8 runs each (README).

    Scripted stall: a region below its whole range stalls, so the first proposal does
    (once: the shipped rule from the expensive test on),
    and that proposal is a step away from the corrected model's (verified worse), so the
    expensive test starts where a step still gains. Unscripted, the corrected model's
    own first proposal reached the optimum with OpenBLAS's Sandybridge kernels and left
    the test nothing to find, while with its Haswell kernels it gained nothing. The data
    hide a tension effect the model lacks: the misfit stays systematic. The
    same calibration with the expensive local phase going on after the round (the
    rule before) spends more expensive runs for no better a point. Where the budget left
    cannot hold the expensive test, it is not started."""
    from surrogate.calibration import _fidelity
    from surrogate.calibration._calibrate import run_calibration

    shipped_radius = _fidelity.MIN_RADIUS
    shipped = _fidelity.CorrectedCalibration._expensive_round
    shipped_next = _fidelity.CorrectedCalibration._next
    thin_soft, thick = TRUTHS[1], " ".join(f"{k} = {v}" for k, v in THICK.items())
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}

    def away(self):
        """The first proposal half a step away from the corrected model's (in the unit box)."""
        theta = shipped_next(self)
        if theta is None or getattr(self, "went_away", False):
            return theta
        self.went_away = True
        space, best = self.problem.space, self.best().theta
        unit = space.to_unit(best) - 0.5 * (space.to_unit(theta) - space.to_unit(best))
        return space.from_unit(np.clip(unit, 0.0, 1.0))[0]

    def calibrate(folder, expensive_round, budget=None):
        def once(self):  # the stall is scripted once: the rounds after it are the shipped rule's
            monkeypatch.setattr(_fidelity, "MIN_RADIUS", shipped_radius)
            return expensive_round(self)

        monkeypatch.setattr(_fidelity, "MIN_RADIUS", 1.01)
        monkeypatch.setattr(_fidelity.CorrectedCalibration, "_expensive_round", once)
        monkeypatch.setattr(_fidelity.CorrectedCalibration, "_next", away)
        path = _calibration_study(
            log_runs / folder, DIAGNOSIS_TESTS, thin_soft, hidden=hidden, seed=1, settings=thick
        )
        return run_calibration(path, progress=False, record=False, max_solver_calls=budget)

    rounds = []

    def spy(self):
        before = (self.runs.calls, self.correction.n_runs, self.best().rmse)
        handed_back = shipped(self)
        rounds.append((before, (self.runs.calls, self.correction.n_runs, self.best().rmse)))
        return handed_back

    found, loop = calibrate("handed", spy)
    (before, after), *_ = rounds
    calls, learned, rmse = before
    p, G = len(loop.problem.space), len(loop.problem.groups)
    assert after[0] - calls >= (p + 1) * G  # its Jacobian and its step
    assert after[1] - learned == after[0] - calls  # each of its runs taught the correction
    assert after[2] < rmse  # a better point, verified
    assert loop.fallen_back is None  # the corrected model went on from there, not the local phase
    assert found.status == "converged" and found.misfit == "systematic", found.message

    # the expensive local phase instead: more runs to its optimum with OpenBLAS's Haswell
    # kernels; with its Sandybridge ones (and, since a Jacobian the budget cannot hold is
    # not started, with its SkylakeX ones) the budget short of one; no better a point
    # either way
    before_rule, _ = calibrate("local", lambda self: False)
    assert found.solver_calls < before_rule.solver_calls or (
        before_rule.status == "budget_exhausted"
        and found.solver_calls <= before_rule.solver_calls + p * G  # its Jacobian at most
    ), before_rule.message
    assert found.rmse_n <= before_rule.rmse_n * (1.0 + 1e-3)

    # a budget that cannot hold the test's Jacobian does not start it: nothing is spent
    # on runs that could tell nothing, and the message says to raise it
    short, loop = calibrate("short", shipped, budget=calls + p * G - 1)
    assert short.solver_calls == calls and loop.short is not None, loop.short
    assert short.status == "budget_exhausted" and "raise --budget" in short.message
    assert "short of the" in short.message  # why: the fit at the best point says it


@pytest.mark.slow
def test_a_stall_at_a_point_the_expensive_test_brings_within_the_noise_certifies_it(
    distorted_solver, log_runs, monkeypatch
):
    """The other side of the rule above: where the expensive test's step verified a point
    whose misfit the noise explains, what is left is the certificate, not a gain the data
    can tell: no proposal of the corrected model follows (on the distorted solver's 1 %
    ripple such a proposal spent the two runs the certificate needed). The certificate
    is the corrected model's first-order test at that point, now taught the expensive
    Jacobian, or where it fails there the expensive solver's own local phase: which of
    the two depends on the path (with OpenBLAS's Haswell kernels the local phase went on
    to 22 expensive runs; with its Sandybridge kernels the corrected test held at the
    expensive step's point, 16 runs). Scripted stall as above, but only once the best
    verified point is within twice the noise: with OpenBLAS's SkylakeX kernels (an AVX-512
    EPYC) the first trust-region update came at 0.65 N, 13 × the noise, where the
    expensive test's step found nothing and the scenario never arose."""
    from surrogate.calibration import _fidelity
    from surrogate.calibration._calibrate import run_calibration

    shipped_radius = _fidelity.MIN_RADIUS
    shipped_manage = _fidelity.CorrectedCalibration._manage_radius

    def stall_near_the_noise(self, taught):
        scripted = not rounds and self.best().rmse <= 2.0 * self.noise
        monkeypatch.setattr(_fidelity, "MIN_RADIUS", 1.01 if scripted else shipped_radius)
        return shipped_manage(self, taught)

    monkeypatch.setattr(_fidelity.CorrectedCalibration, "_manage_radius", stall_near_the_noise)
    shipped, rounds = _fidelity.CorrectedCalibration._expensive_round, []
    shipped_next, proposals = _fidelity.CorrectedCalibration._next, []

    def spy(self):
        before = self.best().rmse
        rounds.append((before, shipped(self), self.best(), self.runs.calls))
        return rounds[-1][1]

    def next_spy(self):
        proposals.append(self.runs.calls)
        return shipped_next(self)

    monkeypatch.setattr(_fidelity.CorrectedCalibration, "_expensive_round", spy)
    monkeypatch.setattr(_fidelity.CorrectedCalibration, "_next", next_spy)
    settings = " ".join(f"{k} = {v}" for k, v in THICK.items())
    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[0], seed=1, settings=settings)
    found, loop = run_calibration(path, progress=False, record=False)
    (before, handed_back, better, calls), *_ = rounds
    assert better.rmse < before and loop.p_value_at(better) >= 0.01  # within the noise
    assert not handed_back and max(proposals) < calls  # no proposal after it
    if loop.fallen_back is None:  # the corrected model's test held at the step's point
        assert found.rmse_n == better.rmse and found.solver_calls == calls
    assert found.status == "converged" and found.misfit == "within the noise", found.message


def test_the_probes_run_after_a_corrected_optimum_the_expensive_solver_ran(
    distorted_solver, log_runs, monkeypatch
):
    """Where the built-in curves leave a parameter free, the expensive solver's next runs
    after the corrected model's optimum are the probes along the least determined
    direction, whether or not it ran the optimum (the choice was read after the first
    runs had taught the correction: from then on the probes ran only where the optimum
    failed)."""
    from surrogate.calibration._fidelity import CorrectedCalibration

    class Enough(Exception):
        pass

    taught: list[tuple[np.ndarray, bool]] = []
    probes: list[list[list[np.ndarray]]] = []
    teach, probe = CorrectedCalibration._teach, CorrectedCalibration._probes

    def spy_teach(self, theta):
        taught.append((np.array(theta), teach(self, theta)))
        if len(taught) == 2:
            raise Enough
        return taught[-1][1]

    def spy_probes(self, fit, ran):
        probes.append(probe(self, fit, ran))
        return probes[-1]

    monkeypatch.setattr(CorrectedCalibration, "_teach", spy_teach)
    monkeypatch.setattr(CorrectedCalibration, "_probes", spy_probes)
    truth = TRUTHS[0]
    settings = " ".join(f"{k} = {v}" for k, v in THICK.items())
    path = _calibration_study(log_runs / "cal", BENDING, truth, seed=0, settings=settings)
    with pytest.raises(Enough):
        surrogate.calibrate(path, progress=False)
    assert taught[0][1], "the expensive solver ran the corrected optimum"
    assert len(probes) == 1 and probes[0], "the built-in curves leave a parameter free here"
    assert np.array_equal(taught[1][0], probes[0][0][0])  # the first probe, the next run


@pytest.mark.slow
def test_the_held_out_error_of_a_verified_fit_without_its_jacobian_is_the_corrected_models(
    distorted_solver, log_runs
):
    """Where the expensive solver's own local phase spent the budget before its Jacobian
    (NaN), the diagnosis's held-out error takes the corrected model's Jacobian at that
    point — a NaN there made a confirmed effect (ΔBIC −1538 on CalculiX) "unexplained"."""
    from dataclasses import replace

    from surrogate.calibration._calibrate import run_calibration
    from surrogate.calibration._diagnose import _heldout, _verified_refit
    from surrogate.calibration._problem import CalibrationProblem

    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    path = _calibration_study(log_runs / "cal", BENDING, truth, seed=0)
    found, loop = run_calibration(path, progress=False, record=False, certify=False)
    fit = loop.best_fit()  # the corrected model's test, as a diagnosis's calibration ends
    assert fit is not None and np.all(np.isfinite(fit.jacobian))
    problem = CalibrationProblem(loop.problem.spec, loop.problem.data, ())
    expected = _heldout(problem, fit.residual, fit.jacobian, fit.at_bound, found.noise_n)
    loop.fits = [replace(fit, jacobian=np.full_like(fit.jacobian, np.nan))]
    low_before, expensive_before = loop.low_fidelity_runs, loop.runs.calls
    heldout = _verified_refit(problem, loop, found.noise_n).heldout_rmse
    assert np.isfinite(heldout)
    # the test's fit took its Jacobian from the corrected model too, at the same point
    assert heldout == pytest.approx(expected, rel=1e-6)
    assert loop.low_fidelity_runs >= low_before  # built-in runs, counted; no expensive one
    assert loop.runs.calls == expensive_before
    assert found.solver_calls == loop.calibration_calls


def _spent(result):
    """The expensive runs a calibration made: its own (``solver_calls``, within its budget)
    and the checks of its profile ends (at most 10, on top)."""
    return result.solver_calls + (
        (result.determination or {}).get("verification_solver_calls") or 0
    )


def test_not_carried_judges_the_inherited_correction_at_its_first_point():
    """The rule for a correction learned on another model: a prediction off by more
    than the tolerance at the corrected optimum, whatever its standard deviation."""
    from surrogate.solvers._fidelity import not_carried

    assert not_carried(0.04, 0.01, 0.05) is None  # within the tolerance
    assert not_carried(0.003, 0.102, 0.0525) is None  # an uncertain but right prediction
    said = not_carried(0.414, 0.139, 0.047)  # CalculiX, hidden hardening: 2.98 σ
    assert said is not None and "missed by 0.414" in said
    assert not_carried(1.81, 2.38, 0.046) is not None  # hidden tension: 0.76 σ


@pytest.mark.slow
def test_a_correction_learned_on_another_model_is_corrected_locally_where_it_missed(
    distorted_solver, log_runs
):
    """A calibration with an effect added, inheriting the correction the model without it
    learned, run as a diagnosis confirms a leader (the only calibration that inherits one:
    no certificate, no intervals, the leader's rule stopping the expensive runs near the
    noise): where the correction has not learned the new model's region (here the
    expensive solver stiffens with the effect, which the model without it never showed) it
    misses at the first point; the built-in model corrected by the verified points' own
    discrepancy then steps towards the expensive optimum, G runs a step, and reaches the
    noise floor within the budget (the expensive solver's own local phase from the first
    point spent all 30 runs, at 0.97-9.4 × noise on seeds 1-4); the same model calibrated
    again with its own correction is not judged.

    Run as a plain calibration (certified, no rule) the count after the noise floor is a
    cliff, not the steps': on a 2-core EPYC without AVX-512 (OpenBLAS Haswell, numpy
    X86_V3) the third point was at 0.98-1.22 × noise on seeds 0-5 (9 runs), then the
    corrected model's proposals and, where the budget left held its 15-run Jacobian, the
    expensive solver's own test took the rest: 30/24/24/30/24/24 runs on seeds 0-5 (seed
    3: two proposals at 8.3 and 2.4 × noise stalled the region at 15 runs, the test's
    Jacobian took the last 15 and its step found none left; seed 0: the certificate took
    them), where the AVX-512 host had 21/27/21/18 on seeds 1-4."""
    from surrogate.calibration._calibrate import run_calibration
    from surrogate.calibration._diagnose import _leader_settled
    from surrogate.calibration._fidelity import CurveCorrection

    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.006, "k_s": 0.006}}
    path = _calibration_study(
        log_runs / "diag", DIAGNOSIS_TESTS, truth, hidden=hidden, seed=3, settings="stiffened = 0.3"
    )
    _, base = run_calibration(path, progress=False, record=False)
    learned = base.correction

    def again(effects, **options):
        inherited = CurveCorrection(learned.Z, learned.D)
        return run_calibration(
            path, effects=effects, progress=False, record=False, correction=inherited, **options
        )

    before = _expensive_runs(log_runs)
    found, loop = again(("tension",), certify=False, intervals=False, enough=_leader_settled)
    assert loop.uncarried is not None and loop.dropped is None
    assert loop.uncarried.startswith("at the corrected model's optimum the correction learned")
    checks = (found.determination or {}).get("verification_solver_calls", 0)  # profile ends
    assert found.solver_calls + checks == _expensive_runs(log_runs) - before
    assert loop.settled is not None  # the rule stopped it: at the noise floor, not the budget
    assert found.solver_calls < 30
    assert found.rmse_n <= 1.3 * found.noise_n, found.message

    _, same = again(())
    assert same.uncarried is None and same.dropped is None  # where its correction learned


@pytest.mark.slow
def test_a_budget_below_todays_design_is_the_corrected_loops_to_spend(distorted_solver, log_runs):
    """With the built-in solver as the prior, a calibration needs one expensive
    verification (a run at each condition group), not an initial design on the expensive
    solver: a budget of 4 at two condition groups is spent — every expensive run counted,
    the answer's RMSE the expensive solver's own there — while the single-fidelity loop
    (``multi_fidelity = false``) refuses it before any run (a floor of 10 for every
    calibration refused both)."""
    truth = TRUTHS[0]
    path = _calibration_study(log_runs / "small", BENDING, truth)
    before = _expensive_runs(log_runs)
    result = surrogate.calibrate(path, max_solver_calls=4, progress=False)
    assert result.solver_calls == _expensive_runs(log_runs) - before
    assert 2 <= result.solver_calls <= 4 and result.multi_fidelity["dropped"] is None
    coat = {k: result.params[k] for k in ("ecoat_gpa", "scoat_gpa", "tcoat_mm")}
    assert result.rmse_n == pytest.approx(_truth_rmse(path, coat), rel=1e-9)
    # measured: budget_exhausted at 2.2 × the truth's RMSE, "… raise --budget"
    assert result.status == "converged" or "raise --budget" in result.message, result.message

    # a budget of one verification, at a point the expensive solver cannot run: the
    # message names the budget as well as the ranges
    failing = path.read_text().replace(
        'kind = "test-distorted"', 'kind = "test-distorted"\nfail_above_tcoat_mm = 0.005'
    )
    path.write_text(failing)
    with pytest.raises(surrogate.InputDataError) as error:
        surrogate.calibrate(path, max_solver_calls=2, progress=False)
    said = str(error.value)
    assert "found no parameter point the solver could run at every test" in said
    assert "all 2 solver runs of the budget were spent: raise --budget, or check" in said
    path.write_text(failing.replace("\nfail_above_tcoat_mm = 0.005", ""))

    single = 'kind = "test-distorted"\nmulti_fidelity = false'
    path.write_text(path.read_text().replace('kind = "test-distorted"', single))
    runs = _expensive_runs(log_runs)
    with pytest.raises(surrogate.InputDataError, match="it needs at least 10 solver runs"):
        surrogate.calibrate(path, max_solver_calls=4, progress=False)
    assert _expensive_runs(log_runs) == runs


@pytest.mark.slow
def test_a_diagnosis_recalibration_on_the_expensive_solver_does_not_certify(
    distorted_solver, log_runs, monkeypatch
):
    """A diagnosis's recalibration handed no correction runs on the full solver; on an
    external solver's multi-fidelity study it spends, like the diagnosis's other
    calibrations, no p × G expensive runs on a certificate. (Since 77373df ``diagnose``
    hands the correction on even where the calibration dropped it, so this guards
    ``_recalibrate``'s own contract, not a path ``diagnose`` takes today.)"""
    from surrogate.calibration import _diagnose, _fidelity
    from surrogate.calibration._problem import load_calibration

    made = []
    init = _fidelity.CorrectedCalibration.__init__

    def spy(self, *args, **kwargs):
        made.append(kwargs.get("certify", True))
        init(self, *args, **kwargs)

    monkeypatch.setattr(_fidelity.CorrectedCalibration, "__init__", spy)
    path = _calibration_study(log_runs / "cal", BENDING, TRUTHS[0], settings="thick = 0.15")
    spec, data, _, noise = load_calibration(path, None, ())
    _diagnose._recalibrate((spec, data, ("hardening",), "hardening", noise, None))
    assert made == [False]
