"""The calibration reaches the noise floor on a seeded sweep of data sets, says so only
when it has checked it, and does not depend on the machine.

The data sets are those of ``benchmarks/calibration.py`` (``surrogate.calibration._synthetic``):
made by the built-in solver, with the truth known to the test and never to the
calibration. The benchmark runs all of them with two seeds; here, four of them
(four coatings, both noise levels, two study seeds) and a misspecified one.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import surrogate
from surrogate import Rig
from surrogate.calibration._calibrate import calibration_note
from surrogate.calibration._local import bound_sides
from surrogate.calibration._problem import coat_section
from surrogate.calibration._synthetic import (
    calibration_sets,
    hidden_effect_tests,
    synthetic_measurements,
    write_calibration_study,
)
from surrogate.study._spec import load_study
from tests.studies import write_study

SETS = {case["name"]: case for case in calibration_sets()}


def _combinations(params):
    return coat_section(params, Rig().thickness_mm)  # the studies use the default rig


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "seed"),
    [("mid-n2", 0), ("thin-soft-n1", 1), ("thick-stiff-n3", 0), ("early-yield-n2", 1)],
)
def test_calibration_reaches_the_noise_floor_and_says_so(tmp_path, name, seed):
    case = SETS[name]
    path = write_calibration_study(tmp_path, case, seed=seed)
    result = surrogate.calibrate(path, progress=False)
    at_truth = surrogate.compare(path, params=case["coating"], plots=False, progress=False).rmse_n
    # the noise floor of design.md §6: RMSE within 5 % of the truth's own on these data,
    # D and Mp within 5 % (the curves determine them; Ecoat and Tcoat apart they do not)
    assert result.rmse_n <= 1.05 * at_truth, result.message
    d, mp = _combinations(result.params)
    d0, mp0 = _combinations(case["coating"])
    assert d == pytest.approx(d0, rel=0.05) and mp == pytest.approx(mp0, rel=0.05)
    assert result.status == "converged", result.message
    assert "local optimum" in result.message and "not at a verified" not in result.message
    # data made by the model itself: the F-test finds no systematic misfit
    assert result.misfit == "within the noise" and result.misfit_p_value >= 0.01
    combos = result.determination["combinations"]
    for key, value in (("bending_stiffness_nmm", d), ("plastic_moment_n", mp)):
        entry = combos[key]
        assert entry["value"] == pytest.approx(value, rel=1e-9)
        assert entry["low"] < value < entry["high"]
        assert entry["relative_half_width"] < 0.05  # determined, not merely bounded
    assert "the curves determine D ∝ Ecoat·Tcoat to ±" in result.message
    assert result.solver_calls <= 200


@pytest.mark.slow
def test_a_model_that_cannot_fit_converges_with_a_systematic_misfit(tmp_path):
    case = SETS["misspecified-n1"]  # a hidden tension effect, the base model
    result = surrogate.calibrate(write_calibration_study(tmp_path, case), progress=False)
    assert result.status == "converged", result.message
    assert result.misfit == "systematic" and result.misfit_p_value < 1e-6
    assert result.rmse_n > 3 * result.noise_n
    assert "systematic" in result.message and "within the noise" not in result.message


@pytest.mark.slow
def test_a_surrogate_that_has_not_learned_the_space_does_not_end_the_global_phase(tmp_path):
    """Strong hidden membrane bending (``benchmarks/diagnosis.py``'s data set 20: six
    tests, replicates, noise 0.05 N), calibrated with it. The surrogate of the
    four-parameter model's curves missed its first verifications by 80–95 % of the
    RMSE; counted as verifications without improvement they ended the global phase
    after 16 runs, and the local phase from its best point (2.3 N) stopped in a local
    optimum at 1.11 N, 21.5 × the truth's RMSE, "converged" with a systematic misfit.
    A run the surrogate missed by more than half taught it a region it had not
    learned: the search goes on, and finds the truth's basin.

    The path is chaotic, and another BLAS may take any of them: this data with its forces
    moved by 1e-12 (relative), 100 variants on the default budget of 200 runs: 95
    ``converged`` within the noise at 0.990–0.992 × the truth's RMSE; five spent the
    budget, three within the noise at 0.991–0.996 ×, one at 1.053 × and one at 1.264 ×
    (its local phase's first fit still walking the flat D–Mp valley towards Ecoat's
    lower bound). The same 100 with 300 runs (the global phase then has 150): 98
    ``converged`` within the noise at 0.990–0.992 ×, the truth's d0 inside the stated
    interval each time, in 70–244 runs (median 104); two without the certificate at
    that bound, within the noise at 0.991 and 0.994 × (one spent the 300 runs:
    ``budget_exhausted``; one stopped at 236 after four rounds whose Jacobian was not
    trusted: ``stalled``), which the result says. The test gives the calibration 300
    runs and asserts what held on every variant (README, "Measurements, calibration and
    compare")."""
    truth = {"ecoat_gpa": 0.8, "scoat_gpa": 0.1, "tcoat_mm": 0.015}
    hidden = {"membrane_bending": {"d0_nmm": 3.0}}
    table = synthetic_measurements(
        hidden_effect_tests(20), coating=truth, effects=hidden, noise_n=0.05, seed=20
    )
    study = '[study]\nname = "membrane"\n[measurements]\nfile = "tests.csv"\n'
    path = write_study(tmp_path, table, study, ranges=True)  # the diagnosis benchmark's ranges
    result = surrogate.calibrate(
        path, effects=["membrane_bending"], max_solver_calls=300, progress=False
    )
    at_truth = surrogate.compare(
        path,
        params={**truth, "membrane_bending.d0_nmm": 3.0},
        effects=["membrane_bending"],
        plots=False,
        progress=False,
    ).rmse_n
    assert result.rmse_n <= 1.05 * at_truth, result.message
    assert result.misfit == "within the noise", result.message
    if result.status == "converged":
        entry = result.determination["intervals"]["membrane_bending.d0_nmm"]
        # an open side is the range's end: the truth within the range is on its side
        assert (entry["low"] is None or entry["low"] < 3.0) and (
            entry["high"] is None or 3.0 < entry["high"]
        ), entry
    else:  # the truth's basin found, not its certificate: said so
        assert result.status in ("budget_exhausted", "stalled"), result.message
        assert result.determination is None
        assert "not at a verified local optimum" in result.message


def test_a_budget_too_small_says_budget_exhausted_and_claims_nothing(tmp_path):
    path = write_calibration_study(tmp_path, SETS["mid-n1"])
    result = surrogate.calibrate(path, max_solver_calls=18, progress=False)
    assert result.status == "budget_exhausted"
    assert result.solver_calls <= 18
    assert result.rmse_n > 1.2 * result.noise_n  # the best point so far fails the F-test
    assert result.misfit is None and result.misfit_p_value is None
    assert result.determination is None
    assert "raise --budget" in result.message and "converged" not in result.message
    assert "within the noise" not in result.message


def test_a_fit_that_stops_with_runs_left_does_not_say_raise_the_budget(tmp_path, monkeypatch):
    """Four rounds whose first-order test found nothing better end the local phase with
    runs left (the test scripted to find nothing, as on a rough response): the message
    gives the fit's reason and says the budget was not the limit (where the budget runs
    out first it says to raise it: the two tests below)."""
    from surrogate.calibration import _local

    def nothing_better(model, x):
        return _local._FirstOrderTest(False, 0.01, None, x, "scripted: nothing better")

    monkeypatch.setattr(_local, "_first_order_test", nothing_better)
    path = write_calibration_study(tmp_path, SETS["mid-n1"])
    stalled = surrogate.calibrate(path, max_solver_calls=200, progress=False)
    assert stalled.status == "stalled" and stalled.solver_calls < 200
    assert "not at a verified local optimum: scripted: nothing better" in stalled.message
    assert "the budget was not the limit" in stalled.message
    assert "raise --budget" not in stalled.message


def test_a_budget_spent_at_a_point_within_the_noise_says_the_model_fits_but_not_where(tmp_path):
    """Four more runs and the best verified point passes the F-test (RMSE 0.99 × the
    noise, p 0.56 here) before the first-order test holds: a local optimum fits at
    least as well, so the misfit is stated; what the curves determine is not."""
    path = write_calibration_study(tmp_path, SETS["mid-n1"])
    result = surrogate.calibrate(path, max_solver_calls=22, progress=False)
    assert result.status == "budget_exhausted"
    assert result.misfit == "within the noise" and result.misfit_p_value >= 0.01
    assert result.determination is None and result.predicted_gain is None
    assert "raise --budget" in result.message and "converged" not in result.message
    assert "already within the noise" in result.message
    assert "stated only at a verified local optimum" in result.message


def _bounded_study(folder):
    """mid-n1 with Ecoat ≤ 1 GPa and Tcoat ≤ 0.015 mm: no point of the ranges makes the
    truth's bending stiffness (1.2 GPa, 0.02 mm), so the fit presses against them."""
    path = write_calibration_study(folder, SETS["mid-n1"])
    text = path.read_text()
    for declared in ("low = 0.5,  high = 4.0", "low = 0.01, high = 0.1"):
        assert declared in text  # the template's ranges, as replaced below
    text = text.replace("low = 0.5,  high = 4.0", "low = 0.5,  high = 1.0")
    path.write_text(text.replace("low = 0.01, high = 0.1", "low = 0.01, high = 0.015"))
    return path


def test_a_budget_spent_at_a_bound_of_a_range_says_so_and_what_would_tell(tmp_path):
    """The budget runs out with the best point on the bounds: the message names each
    coating parameter at a bound — and none that is not — and says a wider range would
    tell. (Swept by hand, seeds 0–5 at 24, 30 and 36 runs: every unconverged point at a
    bound said so, the one inside the ranges said nothing.) Converged there, the
    determination says which the fit holds and the same advice follows."""
    path = _bounded_study(tmp_path / "spent")
    result = surrogate.calibrate(path, max_solver_calls=30, progress=False)
    assert result.status == "budget_exhausted", result.message
    space = load_study(path).space
    sides = bound_sides(space.to_unit(np.array([[result.params[n] for n in space.names]]))[0])
    labels = {"ecoat_gpa": "Ecoat", "scoat_gpa": "Scoat", "tcoat_mm": "Tcoat"}
    assert np.any(sides != 0), result.params  # E·T short of the truth's: the fit pushes out
    for p, side in zip(space, sides, strict=True):
        said = f"{labels[p.name]} at its {'lower' if side < 0 else 'upper'} bound"
        assert (said in result.message) == (side != 0), (p.name, result.message)
    assert "the search stops at the declared ranges: widen" in result.message

    done = surrogate.calibrate(_bounded_study(tmp_path / "done"), progress=False)
    assert done.status == "converged", done.message
    assert set(done.determination["held_at_bound"]) == {"ecoat_gpa", "tcoat_mm"}
    # the fit presses D against the top of the box: the curves bound it from below only
    stiffness = done.determination["combinations"]["bending_stiffness_nmm"]
    assert stiffness["kind"] == "lower-bound" and stiffness["high"] is None, stiffness
    note = "\n".join(calibration_note(done.to_json()))  # the dashboard's and the report's words
    assert "| bending_stiffness_nmm | " in note and "a lower bound only" in note
    assert done.message.endswith(
        "Tcoat held at its upper bound 0.015 — the search stops at the declared ranges: "
        "widen them in the study file to see whether a fit beyond is better"
    )


def _calibrate_in_a_process(path, threads):
    """The calibrated parameters from a fresh interpreter with ``threads`` BLAS threads."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}
    code = (
        "import json, sys, surrogate; r = surrogate.calibrate(sys.argv[1], progress=False, "
        "record=False); print(json.dumps(r.to_json()))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout)


@pytest.mark.slow
def test_the_calibrated_point_does_not_depend_on_threads_or_one_ulp(tmp_path):
    """BLAS threads do not change the calibration at all: every API function computes
    with one BLAS thread (``one_blas_thread_within``), so two threads give the one
    thread's result to the last digit (without it this data's RMSE moved by 2.3e-9 N on the
    2-core AMD EPYC, and other data took another path). A 1e-12 relative change of every
    measured force moves the calibrated D and Mp by less than their stated 95 %
    intervals. One calibration with one thread on the data, one with two threads on the
    data and one with two threads on the data changed by an ulp."""
    case = SETS["mid-n1"]
    one = _calibrate_in_a_process(write_calibration_study(tmp_path / "t1", case), 1)
    two = _calibrate_in_a_process(write_calibration_study(tmp_path / "t2", case), 2)
    for key in ("params", "rmse_n", "solver_calls", "status", "determination"):
        assert two[key] == one[key], key
    path = write_calibration_study(tmp_path / "ulp", case)
    table = pd.read_csv(tmp_path / "ulp" / "tests.csv")
    rng = np.random.default_rng(7)
    table["force_n"] *= 1.0 + 1e-12 * rng.standard_normal(len(table))
    table.to_csv(tmp_path / "ulp" / "tests.csv", index=False, float_format="%.17g")
    other = _calibrate_in_a_process(path, 2)
    for result in (one, other):
        assert result["status"] == "converged", result["message"]
    reference = one["determination"]["combinations"]
    for key, values in other["determination"]["combinations"].items():
        stated = reference[key]["relative_half_width"]
        assert abs(values["value"] / reference[key]["value"] - 1.0) <= stated, key
