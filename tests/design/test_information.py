"""What a candidate test adds at a profile side's re-fit, on linear models whose answer is
known in closed form (:func:`surrogate.design._information.refit_chi2`).

The quantity is the first parameter ``a``; the alternative fit lies ``step`` from the
optimum along ``a`` with the nuisance moved so the measured curves do not change. The test
rules out the alternative by ``χ² = r·A·(difference/σ)²``; once the nuisance may re-fit
to the test, only what it cannot absorb at the measured curves' expense stays.
"""

from __future__ import annotations

import numpy as np
import pytest

from surrogate.design._information import added_chi2, refit_chi2

N, A, R, NOISE = 40, 30, 2, 0.05
STEP = 0.05  # the alternative's difference on the test [N]: one noise level
WIDE = (np.full(3, -1.0), np.full(3, 1.0))


def _chi2(data_columns, test_columns, box=WIDE):
    data = np.tile(np.asarray(data_columns, dtype=float), (N, 1))
    sensitivity = np.tile(np.asarray(test_columns, dtype=float), (A, 1))
    difference = sensitivity @ np.array([STEP, -STEP, 0.0])  # a up, b down: data unchanged
    gradient = np.array([1.0, 0.0, 0.0])  # q = a, held
    plain = added_chi2(np.zeros(A), difference, NOISE, R)
    return plain, refit_chi2(data, sensitivity, difference, gradient, box, NOISE, R)


def test_a_difference_no_other_parameter_changes_stays_whole():
    """The test sees ``a`` alone: no nuisance moves its curve."""
    plain, refit = _chi2([1.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    assert plain == pytest.approx(R * A * (STEP / NOISE) ** 2)
    assert refit == pytest.approx(plain, rel=1e-6)


def test_a_difference_the_measured_curves_pay_for_is_shared():
    """The test sees ``b``, which the measured curves see too (with ``a``): moving ``b`` back
    costs the data what it saves the test, ``χ² = d²·N·r·A/(N + r·A)``."""
    plain, refit = _chi2([1.0, 1.0, 0.0], [0.0, 1.0, 0.0])
    expected = (STEP / NOISE) ** 2 * N * R * A / (N + R * A)
    assert refit == pytest.approx(expected, rel=1e-6)
    assert refit < plain


def test_a_difference_an_unseen_parameter_absorbs_closes_nothing():
    """The test sees ``b`` and ``c``, the measured curves ``a + b`` and not ``c``: ``c`` takes
    the difference at no cost — the test rules out the alternative fit, not its ``a``."""
    plain, refit = _chi2([1.0, 1.0, 0.0], [0.0, 1.0, 1.0])
    assert plain > 10 * 3.84  # far over the threshold alone
    assert refit == pytest.approx(0.0, abs=1e-6 * plain)


def test_a_bound_keeps_what_the_unseen_parameter_cannot_reach():
    """``c`` may move only half the way (its range ends there): a quarter of ``χ²`` stays."""
    half = STEP / 2
    box = (np.array([-1.0, -1.0, -half]), np.array([1.0, 1.0, half]))
    plain, refit = _chi2([1.0, 1.0, 0.0], [0.0, 1.0, 1.0], box=box)
    # with b fixed by its cost to the data, what c cannot take: the least of
    # N·β² + r·A·(d − β − half)² over β, d = STEP
    rest = STEP - half
    expected = (rest / NOISE) ** 2 * N * R * A / (N + R * A)
    assert refit == pytest.approx(expected, rel=1e-4)
    assert 0.0 < refit < plain
