"""What one F60 target determines (``surrogate run``'s statement), checked against the
equally good points: the linear figure is said to hold only where their scatter of the
combination agrees with it, a scatter of the surrogate's points alone leaves it open, and a
span that reaches a declared bound says so.

F60 here is a stand-in with a known law: ``log F60 = log(Ecoat·Tcoat) + c`` (the
combination exactly) or with a saturating Scoat term (F60 depends on more than one
combination across the ranges). Swept over targets, tolerances and the set's size.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from surrogate.identify._identifiability import LINEAR_HOLDS, assess_identifiability
from surrogate.study._space import PAPER_SPACE

NAMES = PAPER_SPACE.names  # ecoat_gpa, scoat_gpa, tcoat_mm


def _linear(X: np.ndarray) -> np.ndarray:
    X = np.atleast_2d(X)
    return np.log(X[:, 0] * X[:, 2] * 1e3)


def _saturating(X: np.ndarray) -> np.ndarray:
    """F60 ∝ D where Mp is large, ∝ Mp where it is small: another combination rules
    there."""
    X = np.atleast_2d(X)
    d, mp = X[:, 0] * X[:, 2] * 1e3, X[:, 1] * X[:, 2] * 3e4
    return np.log(1.0 / (1.0 / d + 1.0 / mp))


def _meeting(law, target: float, tolerance: float, n: int, seed: int) -> np.ndarray:
    """Points of the paper's ranges whose F60 meets the target (a Sobol-like draw)."""
    rng = np.random.default_rng(seed)
    draws = PAPER_SPACE.from_unit(rng.random((200_000, 3)))
    f60 = np.exp(law(draws))
    return draws[np.abs(f60 / target - 1.0) <= tolerance][:n]


def _assess(law, good: np.ndarray, verified: int, target: float, tolerance: float):
    chosen = good[-1]
    return assess_identifiability(
        NAMES,
        chosen,
        law,
        good,
        tolerance=tolerance,
        preference_order=["tcoat_mm"],
        target_n=float(np.exp(law(chosen))[0]),
        verified_good=verified,
        space=PAPER_SPACE,
    )


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(("target", "tolerance"), [(12.0, 0.01), (25.0, 0.02), (40.0, 0.05)])
def test_a_combination_f60_fixes_exactly_is_said_to_hold(seed, target, tolerance):
    good = _meeting(_linear, target, tolerance, 40, seed)
    assert len(good) >= 10
    found = _assess(_linear, good, 3, target, tolerance)
    assert found.linear_check == "holds", found.statement
    assert found.set_spread <= LINEAR_HOLDS * found.relative_uncertainty
    assert "as the linear figure says" in found.statement
    assert "3 verified, " in found.statement
    assert found.set_spread > 0  # the check ran over the other points


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("verified", [True, False])
def test_a_combination_that_holds_near_the_result_only_is_said_to(seed, verified):
    """Where saturation sets F60 in part of the ranges, the points meeting it scatter
    Ecoat·Tcoat far beyond the linear figure at a result where D rules: verified points
    there make that a finding (``fails``), the surrogate's alone leave it open."""
    target, tolerance = 20.0, 0.01
    good = _meeting(_saturating, target, tolerance, 40, seed)
    chosen = good[np.argmax(good[:, 1])]  # the stiffest plastic moment: D sets F60 there
    combination = np.log(good[:, 0] * good[:, 2])
    ends = [int(np.argmin(combination)), int(np.argmax(combination))]
    rest = np.delete(good, ends, axis=0)
    good = np.vstack([rest, good[ends], chosen]) if verified else np.vstack([good, chosen])
    found = assess_identifiability(
        NAMES,
        chosen,
        _saturating,
        good,
        tolerance=tolerance,
        preference_order=["tcoat_mm"],
        target_n=target,
        verified_good=3 if verified else 1,
        space=PAPER_SPACE,
    )
    assert abs(found.exponents["scoat_gpa"]) < 0.5 < abs(found.exponents["ecoat_gpa"])
    assert found.set_spread > LINEAR_HOLDS * found.relative_uncertainty
    if verified:
        assert found.linear_check == "fails", found.statement
        assert "holds near the result only" in found.statement
    else:
        assert found.linear_check == "open", found.statement
        assert "is open (a full-solver run at the farthest would tell)" in found.statement
        assert "1 verified, " in found.statement
    assert "as the linear figure says" not in found.statement


def test_a_span_that_reaches_a_bound_says_so_and_by_which_points():
    """F60 = f(Ecoat·Tcoat): Scoat anywhere, so the points reach both of its bounds; a
    bound only predicted points reach is said to be predicted."""
    good = _meeting(_linear, 12.0, 0.02, 400, 0)
    unit = PAPER_SPACE.to_unit(good)
    low, high = int(np.argmin(unit[:, 1])), int(np.argmax(unit[:, 1]))
    rest = np.delete(good, [low, high], axis=0)
    # the point at Scoat's upper end verified, the one at its lower end predicted
    ordered = np.vstack([rest, good[[low]], good[[high]]])
    found = _assess(_linear, ordered, 1, 12.0, 0.02)
    assert unit[low, 1] < 0.02 and unit[high, 1] > 0.98
    assert found.bounds_reached["scoat_gpa"] == {"low": "predicted", "high": "verified"}
    span = (
        r"Scoat [\d.]+ \(at its lower bound: predicted, not run\)–[\d.]+ "
        r"\(at its upper bound\)"
    )
    assert re.search(span, found.statement), found.statement
    # a bound no point comes near is not said to be reached
    inner = good[(unit[:, 0] > 0.1) & (unit[:, 0] < 0.9)]
    found = _assess(_linear, inner, 1, 12.0, 0.02)
    assert found.bounds_reached["ecoat_gpa"] == {"low": None, "high": None}


def test_without_other_points_nothing_is_claimed_about_the_set():
    chosen = np.array([[1.2, 0.3, 0.01]])
    found = _assess(_linear, chosen, 1, 12.0, 0.01)  # the result alone
    assert found.linear_check == "unchecked"
    assert "No other equally good point was found to check it against" in found.statement
    assert "as the linear figure says" not in found.statement
    with pytest.raises(ValueError, match="verified_good = 2 must lie in 0–1"):
        _assess(_linear, chosen, 2, 12.0, 0.01)


@pytest.mark.parametrize("seed", range(3))
def test_points_the_surrogate_alone_bears_out_leave_the_check_open(seed):
    """Within the linear figure, but no verified point besides the result: open."""
    good = _meeting(_linear, 12.0, 0.01, 30, seed)
    found = _assess(_linear, good, 1, 12.0, 0.01)
    assert found.linear_check == "open", found.statement
    assert "but only the surrogate's predicted points, not run, bear that out" in found.statement
