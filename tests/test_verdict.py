"""The diagnosis's verdict: what it may claim from the leader's figures.

A misfit left after a named effect is called unexplained ("write a plug-in effect")
only where the leader's calibration reached a verified local optimum; where it did not
(its ``unsettled``), the misfit may be the search's and the verdict says that it is
open and what would tell (CalculiX-made curves with hidden hardening: the confirmation
stopped at 5.9 × noise with its budget spent, CalculiX at the truth gives 1.07 ×).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from surrogate.calibration._calibrate import CalibrationResult, unconverged_reason
from surrogate.calibration._statistics import Candidate, verdict

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
    assert "a misfit remains after it (5.5 × noise)" in text
    assert unexplained == {"covariate": "angle_deg", "p_value": 1e-9}
    assert "write a plug-in effect" in text


def test_a_misfit_left_after_an_unsettled_leader_is_open_and_says_what_would_tell():
    unexplained, text = _verdict(_leader(0.277, SPENT))
    assert text.startswith("missing effect: hardening")
    assert f"its calibration on calculix did not settle ({SPENT})" in text
    assert "whether another effect is missing is open" in text
    assert "calibration_solver_calls" in text and "surrogate compare --params" in text
    assert unexplained is None and "plug-in" not in text


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
