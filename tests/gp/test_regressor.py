"""The fast log-marginal likelihood is scikit-learn's, to the last bit, and so are the fits."""

import numpy as np
import pytest
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


CASES = [(nu, d, n) for nu in (1.5, 2.5) for d in (1, 2, 4, 6) for n in (3, 17, 60)]


@pytest.mark.parametrize(("nu", "d", "n"), CASES)
def test_the_likelihood_and_its_gradient_are_scikit_learns_bit_for_bit(nu, d, n, monkeypatch):
    rng = np.random.default_rng(1000 * d + n + int(10 * nu))
    X, y = _data(rng, n, d, duplicate=n > 10)
    kernel = _kernel(d, nu, rng)
    ours = Regressor(kernel=kernel, optimizer=None, normalize_y=True).fit(X, y)
    theirs = GaussianProcessRegressor(kernel=kernel, optimizer=None, normalize_y=True).fit(X, y)
    bounds = kernel.bounds
    thetas = rng.uniform(bounds[:, 0], bounds[:, 1], (20, len(bounds)))  # extremes included
    with monkeypatch.context() as patch:  # ours must not go through the kernel objects
        patch.setattr(Matern, "__call__", _refuse)
        fast = [ours.log_marginal_likelihood(t, eval_gradient=True) for t in thetas]
        values = [ours.log_marginal_likelihood(t) for t in thetas]
    for theta, (value, gradient), plain in zip(thetas, fast, values, strict=True):
        expected, expected_gradient = theirs.log_marginal_likelihood(theta, eval_gradient=True)
        np.testing.assert_array_equal(value, expected)
        np.testing.assert_array_equal(gradient, expected_gradient)
        np.testing.assert_array_equal(plain, expected)
    np.testing.assert_array_equal(ours.kernel_.theta, theirs.kernel_.theta)  # left as fitted


def _refuse(*args, **kwargs):
    raise AssertionError("the fast likelihood called the kernel")


@pytest.mark.filterwarnings("ignore::sklearn.exceptions.ConvergenceWarning")
@pytest.mark.parametrize("nu", [1.5, 2.5])
def test_a_fit_with_restarts_is_scikit_learns(nu):
    rng = np.random.default_rng(7)
    X, y = _data(rng, 25, 3, duplicate=False)
    kernel = _kernel(3, nu, rng)
    ours = Regressor(kernel=kernel, n_restarts_optimizer=3, random_state=0).fit(X, y)
    theirs = GaussianProcessRegressor(kernel=kernel, n_restarts_optimizer=3, random_state=0)
    theirs.fit(X, y)
    np.testing.assert_array_equal(ours.kernel_.theta, theirs.kernel_.theta)
    np.testing.assert_array_equal(ours.alpha_, theirs.alpha_)
    assert ours.log_marginal_likelihood_value_ == theirs.log_marginal_likelihood_value_
    Z = rng.uniform(0.0, 1.0, (5, 3))
    np.testing.assert_array_equal(ours.predict(Z), theirs.predict(Z))


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
