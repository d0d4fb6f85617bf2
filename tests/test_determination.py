"""What the curves determine (pure maths) and the local phase's first-order test, on
linear problems whose answers are known in closed form."""

import math

import numpy as np
import pytest
from scipy import stats

from surrogate.calibration._determination import FREE_SHARE, determine
from surrogate.calibration._local import FIRST_ORDER_BOX, gauss_newton_step

NAMES = ("a", "b")


def _linear_problem(seed, n=200, correlation=0.0):
    """r = y − X z with known X; z in a linear scale on [−10, 10]."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 2))
    X[:, 1] = correlation * X[:, 0] + math.sqrt(1 - correlation**2) * X[:, 1]
    z_true = np.array([0.3, -0.2])
    y = X @ z_true + 0.1 * rng.standard_normal(n)
    z_hat = np.linalg.lstsq(X, y, rcond=None)[0]
    return X, y - X @ z_hat, z_hat


@pytest.mark.parametrize("seed", range(5))
def test_intervals_are_the_textbook_ones_for_a_linear_model(seed):
    X, residual, z_hat = _linear_problem(seed)
    low, high = np.full(2, -10.0), np.full(2, 10.0)
    span = high - low
    found = determine(
        NAMES,
        low,
        high,
        np.array([False, False]),
        z_hat,
        -X * span,  # ∂r/∂u = ∂r/∂z · span
        residual,
        np.zeros(2, dtype=int),
        combinations={"sum": ("exp(a + b)", lambda p: math.exp(p["a"] + p["b"]))},
    )
    dof = X.shape[0] - 2
    s2 = residual @ residual / dof
    covariance = s2 * np.linalg.inv(X.T @ X)
    t = stats.t.ppf(0.975, dof)
    for k, name in enumerate(NAMES):
        half = t * math.sqrt(covariance[k, k])
        np.testing.assert_allclose(found.intervals[name], [z_hat[k] - half, z_hat[k] + half])
    sd_sum = math.sqrt(covariance[0, 0] + covariance[1, 1] + 2 * covariance[0, 1])
    assert found.combinations["sum"]["relative_half_width"] == pytest.approx(
        math.expm1(t * sd_sum), rel=1e-6
    )
    assert found.free == [] and found.held_at_bound == []
    assert found.sigma_n == pytest.approx(math.sqrt(s2))


SUM = {"sum": ("exp(a + b)", lambda p: math.exp(p["a"] + p["b"]))}


def _on_a_valley(X, residual, combinations):
    """``determine`` for a linear problem on [−1, 1]² at (0.2, 0.1)."""
    low, high = np.full(2, -1.0), np.full(2, 1.0)
    return determine(
        NAMES,
        low,
        high,
        np.array([False, False]),
        np.array([0.2, 0.1]),
        -X * (high - low),
        residual,
        np.zeros(2, dtype=int),
        combinations=combinations,
    )


@pytest.mark.parametrize("seed", range(5))
def test_a_valley_leaves_the_parameters_free_but_determines_their_combination(seed):
    """Nearly collinear columns: a and b apart are free, a + b is determined."""
    rng = np.random.default_rng(seed)
    n = 300
    x = rng.standard_normal(n)
    X = np.column_stack([x, x + 1e-4 * rng.standard_normal(n)])
    residual = 0.1 * rng.standard_normal(n)
    found = _on_a_valley(X, residual, SUM)
    assert found.free == ["a", "b"]
    assert found.intervals["a"] == [-1.0, 1.0]  # free: the whole range, not a linearisation
    assert found.combinations["sum"]["relative_half_width"] < 0.05
    # a + b, best determined first: its 95 % half-width (in z) is a small share of the range
    assert found.directions[0]["half_width"] < FREE_SHARE * 2.0
    assert found.directions[0]["weights"]["a"] == pytest.approx(
        found.directions[0]["weights"]["b"], rel=1e-3
    )
    assert "a, b apart are free" in found.statement


def test_a_parameter_at_its_bound_is_held_and_said_so():
    X, residual, z_hat = _linear_problem(0)
    found = determine(
        NAMES,
        np.array([0.01, -10.0]),
        np.array([1.0, 10.0]),
        np.array([True, False]),
        np.array([0.01, z_hat[1]]),
        -X,
        residual,
        np.array([-1, 0]),
    )
    assert found.held_at_bound == ["a"] and found.intervals["a"] is None
    assert found.intervals["b"] is not None
    assert "a held at its lower bound 0.01" in found.statement


def test_a_combination_of_parameters_all_held_at_bounds_is_not_determined():
    """exp(a) with ``a`` held at its bound: the range holds it, the curves do not — no
    interval (it had read "to ±0 %"); exp(a + b) keeps the interval ``b`` gives it."""
    X, residual, z_hat = _linear_problem(0)
    combinations = {
        "a_only": ("exp(a)", lambda p: math.exp(p["a"])),
        **SUM,
    }
    found = determine(
        NAMES,
        np.array([-10.0, -10.0]),
        np.array([10.0, 10.0]),
        np.array([False, False]),
        np.array([-10.0, z_hat[1]]),
        -X * 20.0,
        residual,
        np.array([-1, 0]),
        combinations=combinations,
    )
    assert found.combinations["a_only"]["relative_half_width"] is None
    assert found.combinations["a_only"]["held_by_bounds"] is True
    assert found.combinations["sum"]["held_by_bounds"] is False
    assert found.combinations["a_only"]["value"] == pytest.approx(math.exp(-10.0))
    assert found.combinations["sum"]["relative_half_width"] > 0.0
    assert "exp(a) to" not in found.statement and "exp(a + b) to ±" in found.statement


@pytest.mark.parametrize("seed", range(5))
def test_the_first_order_test_is_zero_at_an_optimum_and_not_away_from_it(seed):
    X, residual, _ = _linear_problem(seed)
    unit = np.array([0.5, 0.5])
    assert gauss_newton_step(residual, -X, unit)[1] == pytest.approx(0.0, abs=1e-9)
    moved = residual - X @ np.array([FIRST_ORDER_BOX, 0.0])  # r at the optimum shifted
    assert gauss_newton_step(moved, -X, unit)[1] > 1e-3


def test_the_first_order_test_lets_a_bound_hold_a_parameter():
    """The optimum lies beyond the upper bound of u₀: at the bound nothing is promised."""
    rng = np.random.default_rng(0)
    X = rng.standard_normal((100, 2))
    y = X @ np.array([2.0, 0.3])
    unit = np.array([1.0, 0.3])  # u₀ held at its upper bound; u₁ at its optimum given u₀
    u1 = np.linalg.lstsq(X[:, 1:], y - X[:, 0], rcond=None)[0][0]
    unit[1] = u1
    residual = y - X @ unit
    assert gauss_newton_step(residual, -X, unit)[1] == pytest.approx(0.0, abs=1e-9)


def test_the_fit_coordinates_round_trip_and_hold_a_clipped_coat_at_its_bound():
    from surrogate.calibration._local import FitCoordinates
    from surrogate.study._space import PAPER_SPACE

    coordinates = FitCoordinates(PAPER_SPACE, 1.2)
    rng = np.random.default_rng(0)
    for unit in rng.random((200, 3)):
        x = coordinates.from_unit(unit)
        assert np.all((x >= -1e-12) & (x <= 1 + 1e-12))  # the declared box lies in [0, 1]³
        np.testing.assert_allclose(coordinates.to_unit(x), unit, atol=1e-12)
    # log D beyond what Ecoat's upper bound gives at this Tcoat: Ecoat is held there
    x = np.array([1.0, 0.5, 0.0])
    unit = coordinates.to_unit(x)
    assert unit[0] == pytest.approx(1.0)
    np.testing.assert_allclose(
        coordinates.canonical(coordinates.canonical(x)), coordinates.canonical(x)
    )
    assert coordinates.canonical(x)[0] < 1.0  # the log D that holds Ecoat exactly at its bound


def test_a_combination_the_valley_hardly_moves_is_determined_to_that_move():
    """Exactly collinear columns: a − b is undetermined. exp(a + b) does not load on it
    (the textbook interval); exp(1.001 a + b) loads on it by 0.001/√2 and moves by 0.002
    along its chord in the box (2√2) — counted in its half-width, not made infinite (a
    rule that made D undetermined on one BLAS and determined on another)."""
    rng = np.random.default_rng(0)
    n = 300
    x = rng.standard_normal(n)
    X = np.column_stack([x, x])
    residual = 0.1 * rng.standard_normal(n)
    tilted = ("exp(1.001 a + b)", lambda p: math.exp(1.001 * p["a"] + p["b"]))
    found = _on_a_valley(X, residual, {**SUM, "tilted": tilted})
    s = math.sqrt(residual @ residual / (n - 2))
    t = stats.t.ppf(0.975, n - 2)
    sxx = math.sqrt(x @ x)
    expected = {"sum": t * s / sxx, "tilted": t * s * 2.001 / (2 * sxx) + 0.002}
    for key, half in expected.items():
        assert found.combinations[key]["relative_half_width"] == pytest.approx(
            math.expm1(half), rel=1e-5
        )
    assert found.free == ["a", "b"]
