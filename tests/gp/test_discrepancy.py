"""The discrepancy GP between two fidelities, and the rules that trust or drop it."""

from __future__ import annotations

import numpy as np
import pytest

from surrogate.gp import Discrepancy
from surrogate.solvers._fidelity import (
    MISSES_IN_A_ROW,
    Correction,
    MissCounter,
    correction_refused,
    too_rough,
)


def _smooth(Z: np.ndarray) -> np.ndarray:
    return 0.02 + 0.01 * Z[:, 0] - 0.005 * Z[:, 1] ** 2 + 0.003 * np.sin(2 * Z[:, 2])


def test_one_run_sets_the_level_everywhere_and_the_spread_grows_away_from_it():
    gp = Discrepancy(0.05, noise_sd=1e-3)
    mean, sd = gp.predict(np.zeros((1, 3)), return_std=True)
    assert mean[0, 0] == 0.0 and sd[0, 0] == 0.05  # no run: the prior
    z = np.array([[0.3, 0.4, 0.5]])
    gp.fit(z, [[0.02]])
    points = np.vstack([z, z + 0.1, z + 10.0])
    mean, sd = gp.predict(points, return_std=True)
    assert np.allclose(mean, 0.02)  # ρ of Kennedy & O'Hagan: the constant mean
    assert sd[0, 0] < 2e-3  # at the run: the solver's own scatter
    assert sd[1, 0] < sd[2, 0]
    # far away: the prior, the mean's own uncertainty and the unknown slopes
    assert sd[2, 0] > 0.05 * np.sqrt(2.0)


@pytest.mark.parametrize("seed", range(5))
def test_a_smooth_discrepancy_is_learned_from_a_few_runs(seed):
    rng = np.random.default_rng(seed)
    Z = rng.random((8, 3))
    gp = Discrepancy(0.05, noise_sd=1e-4).fit(Z, _smooth(Z)[:, None])
    test = rng.random((200, 3))
    mean, sd = gp.predict(test, return_std=True)
    error = mean[:, 0] - _smooth(test)
    spread = np.ptp(_smooth(test))  # what the correction varies by over the inputs: ~1.5 %
    assert np.sqrt(np.mean(error**2)) < 0.1 * spread  # from 8 runs in 3 inputs
    assert np.max(np.abs(error)) < 0.3 * spread  # the corners are extrapolated
    assert np.mean(np.abs(error) <= 1.96 * sd[:, 0]) >= 0.9  # honest 95 % intervals
    assert too_rough(float(gp.scatter[0]), 0.01, what="") is None


def test_a_discrepancy_that_follows_one_input_is_no_noise():
    """The diagnosis's case (its inputs that vary: log D, log Mp, log yield strain, log
    Tcoat, the end tension): two points of the base model at three tension groups, where
    the discrepancy ignores the tension, then one of the model with the tension effect,
    whose stiffer coat moves log D — and the discrepancy follows log D. With a Matérn
    kernel alone (one length scale for every input) the likelihood called the slope
    noise (nugget 0.1, a scatter of 0.7 %: the correction was dropped); the linear part
    takes it."""
    Z = np.array(
        [
            [0.724, 0.338, -0.517, -2.002, 0.000],
            [0.724, 0.338, -0.517, -2.002, 0.291],
            [0.724, 0.338, -0.517, -2.002, 0.582],
            [0.728, 0.340, -0.523, -1.711, 0.000],
            [0.728, 0.340, -0.523, -1.711, 0.286],
            [0.728, 0.340, -0.523, -1.711, 0.571],
            [0.704, 0.316, -0.519, -2.050, 0.000],
            [0.732, 0.344, -0.519, -2.050, 0.281],
            [0.758, 0.370, -0.519, -2.050, 0.508],
        ]
    )
    D = (-0.0228 + 0.04 * (Z[:, 0] - 0.724))[:, None]
    gp = Discrepancy(0.05, noise_sd=1e-3).fit(Z, D)
    assert gp.selected and gp.nugget < 1e-3
    assert too_rough(float(gp.scatter[0]), 0.01, what="") is None
    probe = Z + np.array([0.02, 0.02, 0.0, 0.1, 0.1])
    assert np.allclose(gp.predict(probe)[:, 0], -0.0228 + 0.04 * (probe[:, 0] - 0.724), atol=1e-3)


def test_outputs_share_one_kernel():
    rng = np.random.default_rng(0)
    Z = rng.random((6, 2))
    f = _smooth(np.hstack([Z, Z[:, :1]]))
    gp = Discrepancy(0.05, noise_sd=1e-4).fit(Z, np.column_stack([f, 2 * f, -f]))
    mean = gp.predict(rng.random((10, 2)))
    assert np.allclose(mean[:, 1], 2 * mean[:, 0]) and np.allclose(mean[:, 2], -mean[:, 0])


@pytest.mark.parametrize("seed", range(5))
def test_a_rough_discrepancy_is_called_noise_and_too_rough(seed):
    """±5 % scatter with no structure: the likelihood picks a large nugget, and the
    scatter it attributes to noise fails the rule for a 1 % tolerance."""
    rng = np.random.default_rng(seed)
    Z = rng.random((8, 3))
    gp = Discrepancy(0.05, noise_sd=1e-3).fit(Z, 0.05 * rng.standard_normal((8, 1)))
    assert gp.selected and gp.nugget > 1e-3
    assert too_rough(float(gp.scatter[0]), 0.01, what="in log F60") is not None


def test_misses_in_a_row_drop_the_correction_and_a_hit_resets_them():
    counter = MissCounter()
    assert not counter.judge(0.05, 0.001, 0.01)  # a miss
    assert not counter.judge(0.001, 0.001, 0.01)  # a hit: the count starts again
    assert not counter.judge(0.05, 0.001, 0.01)
    assert counter.judge(-0.05, 0.001, 0.01)  # the second in a row
    assert f"{MISSES_IN_A_ROW} expensive runs in a row" in counter.reason
    # within 3 sd, or within the tolerance, is no miss
    assert not MissCounter().judge(0.05, 0.02, 0.01) and not MissCounter().judge(0.009, 0, 0.01)


def test_the_size_of_a_correction():
    angle = np.arange(0.0, 91.0)
    low = {"angle_deg": angle, "force_n": np.sin(np.radians(angle)), "f60_n": 1.0}
    low["theta_sat_deg"] = 90.0
    high = {**low, "force_n": 0.9 * low["force_n"], "f60_n": 0.9, "theta_sat_deg": 88.0}
    size = Correction.between(low, high)
    assert size.f60_percent == pytest.approx(-10.0)
    assert size.theta_sat_deg == -2.0
    assert size.curve_rmse_relative == pytest.approx(0.1)
    assert correction_refused(size) is None
    worse = {**high, "force_n": 0.7 * low["force_n"], "f60_n": 0.7}
    assert "more than the 25 %" in correction_refused(Correction.between(low, worse))
    # several condition groups: the worst is reported
    assert Correction.between([low, low], [high, worse]).curve_rmse_relative == pytest.approx(0.3)
