"""The fast log-marginal likelihood is scikit-learn's to rounding, and so are the fits; the
rest of the regressor (fits without optimizer, posterior means) is scikit-learn's to the last
bit."""

import math

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern, WhiteKernel

from surrogate.gp._regressor import Regressor


def _kernel(n_features, nu, rng):
    length = rng.uniform(0.1, 3.0, n_features)
    return ConstantKernel(rng.uniform(0.1, 5.0), (1e-3, 1e3)) * Matern(
        length_scale=length, length_scale_bounds=(1e-2, 1e3), nu=nu
    ) + WhiteKernel(10.0 ** rng.uniform(-8, -2), (1e-10, 1e-1))


def _data(rng, n, d, duplicate):
    X = rng.uniform(0.0, 1.0, (n, d))
    if duplicate:
        X[-1] = X[0]  # a repeated input: the white noise alone keeps K positive definite
    y = np.sin(3.0 * X).sum(axis=1) + 0.01 * rng.standard_normal(n)
    return X, y


CASES = [(nu, d, n) for nu in (1.5, 2.5) for d in (1, 2, 4, 7, 9) for n in (3, 17, 60)]


def _assert_scikit_learns_to_rounding(ours, theirs, theta, X):
    """Our value and gradient at ``theta`` against scikit-learn's: within what rounding
    allows a backward-stable solve with ``K``'s condition number (measured: at most 2.1 ×
    cond · ε of the value and 7.7 × of the gradient's largest component, 600 draws), and
    ``-inf`` with a zero gradient where scikit-learn finds ``K`` not positive definite."""
    value, gradient = ours.log_marginal_likelihood(theta, eval_gradient=True)
    expected, expected_gradient = theirs.log_marginal_likelihood(theta, eval_gradient=True)
    assert ours.log_marginal_likelihood(theta) == value
    if expected == -np.inf:
        assert value == -np.inf and not np.any(gradient)
        return
    K = theirs.kernel.clone_with_theta(theta)(X)
    K[np.diag_indices_from(K)] += theirs.alpha
    rounding = 20.0 * np.linalg.cond(K) * np.finfo(float).eps
    assert abs(value - expected) <= rounding * max(abs(expected), 1.0)
    scale = max(np.abs(expected_gradient).max(), 1.0)
    assert np.abs(gradient - expected_gradient).max() <= rounding * scale


@pytest.mark.parametrize(("nu", "d", "n"), CASES)
def test_the_likelihood_and_its_gradient_are_scikit_learns_to_rounding(nu, d, n, monkeypatch):
    rng = np.random.default_rng(1000 * d + n + int(10 * nu))
    X, y = _data(rng, n, d, duplicate=n > 10)
    kernel = _kernel(d, nu, rng)
    ours = Regressor(kernel=kernel, optimizer=None, normalize_y=True).fit(X, y)
    theirs = GaussianProcessRegressor(kernel=kernel, optimizer=None, normalize_y=True).fit(X, y)
    bounds = kernel.bounds
    thetas = rng.uniform(bounds[:, 0], bounds[:, 1], (20, len(bounds)))  # across the bounds
    with monkeypatch.context() as patch:  # ours must not go through the kernel objects
        patch.setattr(Matern, "__call__", _refuse)
        fast = [ours.log_marginal_likelihood(t, eval_gradient=True) for t in thetas]
        plain = [ours.log_marginal_likelihood(t) for t in thetas]
    for theta, (value, _), alone in zip(thetas, fast, plain, strict=True):
        assert alone == value  # without the gradient: the same value
        _assert_scikit_learns_to_rounding(ours, theirs, theta, X)
    np.testing.assert_array_equal(ours.kernel_.theta, theirs.kernel_.theta)  # left as fitted


def _refuse(*args, **kwargs):
    raise AssertionError("the fast likelihood called the kernel")


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
@pytest.mark.parametrize("nu", [1.5, 2.5])
def test_a_fit_with_restarts_is_scikit_learns(nu, monkeypatch):
    rng = np.random.default_rng(7)
    X, y = _data(rng, 25, 3, duplicate=False)
    kernel = _kernel(3, nu, rng)
    calls = _count_matern_calls(monkeypatch)
    ours = Regressor(kernel=kernel, n_restarts_optimizer=3, random_state=0).fit(X, y)
    ours_calls = calls[0]
    theirs = GaussianProcessRegressor(kernel=kernel, n_restarts_optimizer=3, random_state=0)
    theirs.fit(X, y)
    theirs_calls = calls[0] - ours_calls
    assert ours.fast_likelihood_ and ours_calls == 1 < theirs_calls  # ours: fit's final K only
    # the same optimum to the optimizer's tolerance (measured: θ 1e-5 apart, the likelihood
    # 1e-10, predictions 2e-7), and ours no worse
    np.testing.assert_allclose(ours.kernel_.theta, theirs.kernel_.theta, atol=1e-4)
    ours_value, theirs_value = (
        ours.log_marginal_likelihood_value_,
        theirs.log_marginal_likelihood_value_,
    )
    assert ours_value >= theirs_value - 1e-8 * abs(theirs_value)
    Z = rng.uniform(0.0, 1.0, (5, 3))
    np.testing.assert_allclose(ours.predict(Z), theirs.predict(Z), rtol=1e-5, atol=1e-6)


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_another_kernel_takes_scikit_learns_path():
    rng = np.random.default_rng(3)
    X, y = _data(rng, 12, 2, duplicate=False)
    kernel = ConstantKernel() * RBF([1.0, 1.0]) + WhiteKernel(1e-3)
    ours = Regressor(kernel=kernel, random_state=0).fit(X, y)
    theirs = GaussianProcessRegressor(kernel=kernel, random_state=0).fit(X, y)
    np.testing.assert_array_equal(ours.kernel_.theta, theirs.kernel_.theta)


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
@pytest.mark.parametrize(("nu", "d"), [(1.5, 1), (1.5, 3), (2.5, 1), (2.5, 5)])
def test_the_posterior_mean_is_predicts_bit_for_bit(nu, d, monkeypatch):
    rng = np.random.default_rng(int(10 * nu) + d)
    X, y = _data(rng, 30, d, duplicate=False)
    gp = Regressor(kernel=_kernel(d, nu, rng), normalize_y=True, random_state=0).fit(X, y)
    Z = rng.uniform(-0.2, 1.2, (40, d))
    expected = gp.predict(Z)
    with monkeypatch.context() as patch:
        patch.setattr(Matern, "__call__", _refuse)
        mean = gp.posterior_mean(Z)
    np.testing.assert_array_equal(mean, expected)


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_the_posterior_mean_follows_a_refit_and_a_new_theta():
    """:meth:`Regressor.posterior_mean` keeps its scaled training inputs between calls;
    a refit on other runs, or ``theta`` set on the fitted kernel, is ``predict``'s still."""
    rng = np.random.default_rng(5)
    X, y = _data(rng, 20, 3, duplicate=False)
    Z = rng.uniform(0.0, 1.0, (8, 3))
    gp = Regressor(kernel=_kernel(3, 2.5, rng), normalize_y=True, random_state=0).fit(X, y)
    first = gp.posterior_mean(Z)
    np.testing.assert_array_equal(first, gp.predict(Z))
    gp.kernel_.theta = gp.kernel_.theta + 0.3
    np.testing.assert_array_equal(gp.posterior_mean(Z), gp.predict(Z))
    assert not np.array_equal(gp.posterior_mean(Z), first)
    X2, y2 = _data(rng, 25, 3, duplicate=False)
    gp.fit(X2, y2)
    np.testing.assert_array_equal(gp.posterior_mean(Z), gp.predict(Z))


def _count_matern_calls(monkeypatch):
    """Patch ``Matern.__call__`` to count its calls in the returned one-item list."""
    calls = [0]
    original = Matern.__call__

    def counted(self, *args, **kwargs):
        calls[0] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Matern, "__call__", counted)
    return calls


def test_a_fit_without_optimizer_is_scikit_learns_hyperparameters_rounding_included():
    """scikit-learn's fit without optimizer sets ``theta`` once, which rounds each
    hyperparameter through exp(log(·)); its matrices follow from the rounded values
    (a third of hand-made kernels moved). ``OutputGP.from_dict`` fits this way."""
    rng = np.random.default_rng(11)
    for case in range(60):
        d = 1 + case % 4
        X, y = _data(rng, 15, d, duplicate=False)
        kernel = _kernel(d, (1.5, 2.5)[case % 2], rng)
        if case % 3 == 0:  # as from_dict rebuilds it
            kernel = kernel.clone_with_theta(rng.uniform(kernel.bounds[:, 0], kernel.bounds[:, 1]))
        ours = Regressor(kernel=kernel, optimizer=None, normalize_y=True).fit(X, y)
        theirs = GaussianProcessRegressor(kernel=kernel, optimizer=None, normalize_y=True)
        theirs.fit(X, y)
        for name, value in theirs.kernel_.get_params().items():
            if not hasattr(value, "get_params"):
                np.testing.assert_array_equal(ours.kernel_.get_params()[name], value)
        np.testing.assert_array_equal(ours.L_, theirs.L_)
        np.testing.assert_array_equal(ours.alpha_, theirs.alpha_)
        assert ours.log_marginal_likelihood_value_ == theirs.log_marginal_likelihood_value_
        Z = rng.uniform(0.0, 1.0, (4, d))
        np.testing.assert_array_equal(ours.posterior_mean(Z), theirs.predict(Z))


@pytest.mark.parametrize(
    "case", ["two outputs", "isotropic, 3 features", "not positive definite", "array alpha"]
)
def test_other_shapes_are_scikit_learns_too(case):
    rng = np.random.default_rng(5)
    X, y = _data(rng, 12, 3, duplicate=False)
    kernel, alpha = _kernel(3, 2.5, rng), 1e-10
    if case == "two outputs":
        y = np.column_stack([y, np.cos(X).sum(axis=1)])
    if case == "isotropic, 3 features":
        kernel = ConstantKernel(2.0) * Matern(0.7, (1e-2, 1e3), nu=1.5) + WhiteKernel(1e-4)
    if case == "array alpha":
        alpha = rng.uniform(1e-8, 1e-4, len(X))
    theirs = GaussianProcessRegressor(kernel=kernel, optimizer=None, alpha=alpha, normalize_y=True)
    theirs.fit(X, y)
    ours = Regressor(kernel=kernel, optimizer=None, alpha=alpha, normalize_y=True).fit(X, y)
    if case == "not positive definite":  # past fit, which refuses such a K: 1 off K's diagonal
        ours.alpha = theirs.alpha = np.full(len(X), -1.0)
    thetas = rng.uniform(kernel.bounds[:, 0], kernel.bounds[:, 1], (5, len(kernel.theta)))
    if case == "not positive definite":
        thetas[:, 0] = np.log(1e-3)  # C below the 1 taken off the diagonal
    for theta in thetas:
        _assert_scikit_learns_to_rounding(ours, theirs, theta, X)
        if case == "not positive definite":
            assert ours.log_marginal_likelihood(theta) == -np.inf


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
def test_what_the_fast_path_does_not_take():
    rng = np.random.default_rng(9)
    X, y = _data(rng, 10, 2, duplicate=False)
    fixed = ConstantKernel(1.0, "fixed") * Matern([0.5, 0.5], nu=2.5) + WhiteKernel(1e-4)
    assert not Regressor(kernel=fixed, random_state=0).fit(X, y).fast_likelihood_
    gp = Regressor(kernel=_kernel(2, 2.5, rng), random_state=0).fit(X, y)
    with pytest.raises(ValueError, match="theta"):
        gp.log_marginal_likelihood(np.zeros(6))  # scikit-learn's error for a wrong length
    with pytest.raises(NotFittedError):
        clone(gp).posterior_mean(X)
    # length scales that are neither one nor one a feature: scikit-learn's error (the
    # compiled likelihood would have read past theta's end)
    two = ConstantKernel() * Matern([1.0, 1.0], nu=2.5) + WhiteKernel()
    with pytest.raises(ValueError, match="same number of dimensions"):
        Regressor(kernel=two, random_state=0).fit(rng.uniform(size=(10, 6)), np.arange(10.0))


def _plain_cholesky(K):
    """The lower Cholesky factor by the textbook loops, one sum at a time (Python floats:
    the same IEEE double operations in the same order)."""
    n = len(K)
    L = [[0.0] * n for _ in range(n)]
    for j in range(n):
        pivot = K[j][j]
        for k in range(j):
            pivot -= L[j][k] * L[j][k]
        L[j][j] = math.sqrt(pivot)  # correctly rounded, as compiled (pivot**0.5, pow, not always)
        for i in range(j + 1, n):
            s = K[i][j]
            for k in range(j):
                s -= L[i][k] * L[j][k]
            L[i][j] = s / L[j][j]
    return np.array(L)


def _plain_inverse(L):
    """``(L Lᵀ)⁻¹`` by the textbook loops: ``L⁻¹`` column by column, then ``L⁻ᵀ L⁻¹``."""
    n = len(L)
    inv = [[0.0] * n for _ in range(n)]
    for j in range(n):
        inv[j][j] = 1.0 / L[j][j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= L[i][k] * inv[k][j]
            inv[i][j] = s / L[i][i]
    out = [[0.0] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(j, n):
                s += inv[k][i] * inv[k][j]
            out[i][j] = out[j][i] = s
    return np.array(out)


def test_the_compiled_factor_and_inverse_are_the_plain_loops_bit_for_bit():
    """The compiled Cholesky factor and inverse run four sums side by side (for speed);
    each sum keeps the plain loops' order, so every bit of both, zeros' signs included, is the
    plain loops' — on every size, the tails after the groups of four too. A fit's
    trajectory, and so every calibration, does not depend on that speed-up."""
    from surrogate.gp._likelihood import _cholesky, _inverse_from_cholesky

    rng = np.random.default_rng(20261202)
    for n in [*range(1, 14), 18, 31]:
        for _ in range(3):
            A = rng.standard_normal((n, n))
            K = A @ A.T + 0.1 * n * np.eye(n)
            for alone in rng.choice(n, size=n // 3, replace=False):
                K[alone, :] = K[:, alone] = 0.0  # exact zeros in the factor and its inverse
                K[alone, alone] = 1.0
            L, regular = _cholesky(K)
            assert regular
            plain = _plain_cholesky(K.tolist())
            assert np.array_equal(L, plain) and np.array_equal(np.signbit(L), np.signbit(plain))
            inverse, plain = _inverse_from_cholesky(L), _plain_inverse(L.tolist())
            assert np.array_equal(inverse, plain)
            assert np.array_equal(np.signbit(inverse), np.signbit(plain))
    singular = np.ones((5, 5))
    assert not _cholesky(singular)[1]
