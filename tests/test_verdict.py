"""The diagnosis's verdict: what it may claim from the leader's figures.

A misfit left after a named effect is called unexplained ("write a plug-in effect")
unless the leader's figures come from a calibration that stopped before a verified
local optimum (its ``unsettled``, set where an expensive solver confirmed it): they
are then upper bounds, and the verdict says that whether an effect is missing is open
and what would tell (README, "Multi-fidelity": CalculiX-made curves with hidden
hardening, whose confirmation stopped short far from the truth's basin).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from surrogate.calibration._calibrate import CalibrationResult, unconverged_reason
from surrogate.calibration._statistics import Candidate, ranking_label, verdict

NOISE = 0.05
FOLLOWS = [{"covariate": "angle_deg", "significant": True, "p_value": 1e-9}]
SPENT = "not at a verified local optimum: budget spent (30 of 30 solver runs used)"


def _leader(rmse_n: float, unsettled: str | None) -> Candidate:
    return Candidate(
        effect="hardening",
        rmse_n=rmse_n,
        heldout_rmse_n=0.25,
        delta_bic=-93.0,
        params={},
        confirmed_by="calculix",
        unsettled=unsettled,
    )


def _verdict(leader: Candidate):
    return verdict(0.32, 0.333, NOISE, True, 1e-100, [leader], FOLLOWS)


def test_a_misfit_left_after_a_settled_leader_is_unexplained():
    unexplained, text = _verdict(_leader(0.277, None))
    assert text.startswith("missing effect: hardening")
    assert "a misfit remains after it (5.54 × noise)" in text
    assert unexplained == {"covariate": "angle_deg", "p_value": 1e-9}
    assert "write a plug-in effect" in text


def test_a_misfit_left_after_an_unsettled_leader_is_open_and_says_what_would_tell():
    unexplained, text = _verdict(_leader(0.277, SPENT))
    assert text.startswith("missing effect: hardening")
    assert (
        "a misfit remains after it (5.54 × noise); whether another effect is missing is open"
        in text
    )
    assert f"the calibration with `hardening` on calculix stopped short ({SPENT})" in text
    assert (
        "a calibration with it on calculix itself (`surrogate calibrate --effect hardening`" in text
    )
    assert "`[solver] multi_fidelity = false`: calculix's own global phase" in text
    assert "surrogate compare --params" in text
    assert unexplained is None and "plug-in" not in text


def test_an_unsettled_leader_that_is_not_decisive_leaves_the_question_open_too():
    """Its ΔBIC and held-out error are upper bounds as well: "unexplained" would claim
    what the stopped calibration did not show."""
    undecided = replace(_leader(0.277, SPENT), delta_bic=-5.0)
    unexplained, text = _verdict(undecided)
    assert text.startswith("whether an effect is missing is open: the calibration with")
    assert unexplained is None and "plug-in" not in text
    settled = replace(undecided, unsettled=None)
    unexplained, text = _verdict(settled)
    assert unexplained is not None and text.startswith("unexplained: residual follows angle_deg")


def test_a_tied_leader_that_stopped_short_leaves_the_question_open():
    """The data cannot tell the leaders apart, and one of them may fit better than its
    figures say: "unexplained" would claim what its calibration did not show."""
    settled = _leader(0.277, None)
    tied = replace(_leader(0.28, SPENT), effect="membrane_bending", delta_bic=-92.0)
    unexplained, text = verdict(
        0.32, 0.333, NOISE, True, 1e-100, [settled, tied], FOLLOWS, ["membrane_bending"]
    )
    assert text.startswith("missing effect: hardening")
    assert "the calibration with `membrane_bending` on calculix stopped short" in text
    assert unexplained is None and "plug-in" not in text


def test_the_tables_mark_a_ranking_entry_whose_figures_are_upper_bounds():
    assert ranking_label(_leader(0.277, SPENT).to_json()) == "hardening (not settled)"
    assert ranking_label(_leader(0.277, None).to_json()) == "hardening"
    assert ranking_label({"effect": "tension"}) == "tension"  # records written before the key


@pytest.mark.parametrize("unsettled", [None, SPENT])
def test_a_leader_near_the_noise_is_named_alone_settled_or_not(unsettled):
    """Near the noise nothing is left to look for: the figures are an upper bound, and
    they are already small."""
    unexplained, text = _verdict(_leader(0.06, unsettled))
    assert unexplained is None and "misfit remains" not in text and "settle" not in text


def test_the_unconverged_reason_is_the_local_fits_own_where_it_ended_at_the_answer():
    params = {"ecoat_gpa": 1.0, "scoat_gpa": 0.1}
    result = CalibrationResult(
        params=params, rmse_n=0.277, noise_n=NOISE, solver_calls=30, effects=["hardening"],
        rmse_per_test_n={}, status="budget_exhausted", predicted_gain=None, misfit=None,
        misfit_p_value=None, determination=None, iterations=1, study="s", storage="sqlite://",
        message="",
    )  # fmt: skip
    at_answer = SimpleNamespace(theta=np.array([1.0, 0.1]), message=SPENT)
    elsewhere = SimpleNamespace(theta=np.array([1.1, 0.1]), message=SPENT)
    none_there = "no local fit ended at the best verified point"
    assert unconverged_reason(result, at_answer) == SPENT  # type: ignore[arg-type]
    assert unconverged_reason(result, elsewhere) == none_there  # type: ignore[arg-type]
    assert unconverged_reason(result, None) == none_there
    converged = replace(result, status="converged")
    assert unconverged_reason(converged, at_answer) is None  # type: ignore[arg-type]


def _refit(rmse_n: float, n_points: int, p: int, seed: int):
    """A refit with ``n_points`` residuals of RMSE ``rmse_n`` and ``p`` parameters."""
    from surrogate.calibration._diagnose import _Refit

    residual = np.random.default_rng(seed).normal(size=n_points)
    residual *= rmse_n / np.sqrt(np.mean(residual**2))
    names = tuple(f"p{i}" for i in range(p))
    return _Refit(None, names, np.zeros(p), residual, None, rmse_n, set())


@pytest.mark.parametrize("seed", range(4))
def test_a_better_basin_takes_back_only_its_share_of_the_leaders_gain(seed):
    """Where the basin check finds the current model's calibration not at its best and
    cannot replace it (an external solver's), the leader is named only where it still
    beats the better basin decisively: a basin 2.5 % better leaves hardening at the noise
    named (the distorted solver's hidden-hardening curves: 0.645 → 0.629 N, hardening
    0.050 N, noise 0.047 N), a basin at the noise leaves it nothing."""
    from surrogate.calibration._diagnose import _against_basin
    from surrogate.calibration._statistics import bic

    n_points = 364
    current = _refit(0.645, n_points, 3, seed)
    leader_residual = _refit(0.050, n_points, 4, seed + 10).residual

    def leader_against(better_rmse: float) -> float | None:
        better = _refit(better_rmse, n_points, 3, seed + 20)
        delta = bic(float(leader_residual @ leader_residual), n_points, 4) - bic(
            float(current.residual @ current.residual), n_points, 3
        )
        leader = replace(_leader(0.050, None), delta_bic=delta, heldout_rmse_n=0.051)
        return _against_basin(leader, current, better, n_points)

    partly = leader_against(0.629)
    assert partly is not None and -2000 < partly < -10
    assert leader_against(0.0505) is None  # the basin explains the gain: nothing named
    assert leader_against(0.049) is None


@pytest.mark.parametrize("seed", range(3))
def test_a_leader_against_a_calibration_stopped_early_must_beat_a_three_fold_better_fit(seed):
    """A diagnosis with an external solver stops the current model's expensive runs where
    its misfit is systematic beyond doubt; a leader is named on it only where it would be
    decisive against a 3-fold lower RMSE too (else the calibration runs to its end): a
    leader at the noise against a base at 13 × passes, one that only halves the misfit
    does not."""
    from surrogate.calibration._diagnose import _decisive_against_lower
    from surrogate.calibration._statistics import bic

    n_points = 364
    current = _refit(0.645, n_points, 3, seed)
    problem = SimpleNamespace(n_points=n_points)

    def leader(rmse_n: float) -> Candidate:
        residual = _refit(rmse_n, n_points, 4, seed + 10).residual
        delta = bic(float(residual @ residual), n_points, 4) - bic(
            float(current.residual @ current.residual), n_points, 3
        )
        return replace(_leader(rmse_n, None), delta_bic=delta, heldout_rmse_n=1.02 * rmse_n)

    assert _decisive_against_lower([leader(0.050)], current, problem)
    halved = leader(0.32)
    assert halved.delta_bic < -10  # named against the calibration as it stopped
    assert not _decisive_against_lower([halved], current, problem)
    assert _decisive_against_lower([], current, problem)  # nothing named: nothing to rerun
