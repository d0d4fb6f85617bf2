"""scikit-learn's Gaussian process regressor with a fast log-marginal likelihood.

Both of the product's GPs (:mod:`._output`, :mod:`._curves`) use the kernel
``C · Matern(ν, ARD) + White`` and fit its hyperparameters by L-BFGS-B on
scikit-learn's log-marginal likelihood: about 30 evaluations a fit, hundreds of fits
a calibration. Each evaluation sets ``kernel.theta`` and calls the composed kernel,
and that bookkeeping (``get_params``, ``dir``, cloning of hyperparameter objects)
outweighed the arithmetic on the product's tens of runs (``benchmarks/gp_fit.py``, 10–230
runs: fits 2.2–7.6 × and posterior means of a search batch 3.4–8.4 × faster).

:class:`Regressor` evaluates the likelihood of that one kernel from ``theta``
directly, in one compiled call (:mod:`._likelihood`): scikit-learn 1.9's definitions
(``GaussianProcessRegressor.log_marginal_likelihood`` and the kernels' ``__call__`` and
gradients) in loops, the Cholesky factor and the solves included, so that its numbers
do not depend on the BLAS kernels either. They are scikit-learn's to rounding, which
grows with K's condition number: measured on 600 random kernels and data (1 to 9
features, 3 to 60 runs), the value within 2.1 × cond(K)·ε of it and the gradient within
7.7 × cond(K)·ε of its largest component (measured 4e-9 at most where cond(K) < 1e8)
(``tests/gp/test_regressor.py`` holds them within 20 × cond(K)·ε). An earlier version
that repeated scikit-learn's array operations in their order gave the same bits, at 3 to
10 times the cost a call. Where scikit-learn's would set the kernel's ``theta`` as a side
effect, only inside ``fit``'s search is that skipped (its end sets it); any other kernel,
or call, goes to scikit-learn's implementation unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.distance import cdist
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import (
    ConstantKernel,
    Kernel,
    Matern,
    Product,
    Sum,
    WhiteKernel,
)
from sklearn.utils.validation import check_is_fitted

__all__ = ["Regressor"]

FAST_NU = (1.5, 2.5)


def _fast_form(kernel: Kernel | None) -> bool:
    """Whether ``kernel`` is ``C · Matern(ν ∈ FAST_NU) + White`` with every hyperparameter free
    (these classes themselves: a subclass may compute otherwise)."""
    return (
        kernel is not None
        and type(kernel) is Sum
        and type(kernel.k1) is Product
        and type(kernel.k1.k1) is ConstantKernel
        and type(kernel.k1.k2) is Matern
        and type(kernel.k2) is WhiteKernel
        and kernel.k1.k2.nu in FAST_NU
        and not any(h.fixed for h in kernel.hyperparameters)
    )


class Regressor(GaussianProcessRegressor):
    """``GaussianProcessRegressor`` whose hyperparameter fit skips the kernel objects.

    Same parameters, attributes and results as scikit-learn's (the log-marginal
    likelihood the same to rounding, the posterior mean to the last bit); only their
    evaluation is faster.
    The fast likelihood is taken where scikit-learn's leaves the kernel as it is
    (``clone_kernel=True``) and inside ``fit``'s hyperparameter search, whose end sets the
    kernel's ``theta`` anyway. A fit without optimizer keeps scikit-learn's path: there,
    setting ``theta`` rounds each hyperparameter through ``exp(log(·))``, and the fit's
    matrices follow from the rounded values.
    """

    _searching = False  # inside fit's hyperparameter search

    def fit(self, X, y):
        # one length scale, or one a feature: another count is scikit-learn's to refuse
        fast = _fast_form(self.kernel) and self.kernel.n_dims - 2 in (1, np.shape(X)[-1])
        self._n_theta = self.kernel.n_dims if fast else -1
        self._searching = fast and self.optimizer is not None
        try:
            super().fit(X, y)
        finally:
            self._searching = False
        self.fast_likelihood_ = fast
        return self

    def posterior_mean(self, X: np.ndarray) -> np.ndarray:
        """``predict(X)`` of the fitted regressor on one-dimensional targets, without
        scikit-learn's per-call checks and kernel objects: the same numbers (the search's
        hot path, thousands of calls a calibration)."""
        fast = getattr(self, "fast_likelihood_", None)
        if fast is None:
            check_is_fitted(self, "alpha_")  # not the prior's mean, as predict would give
        if fast:
            length_scale, train, nu, constant = self._mean_terms()
            dists = cdist(X / length_scale, train, metric="euclidean")
            K_trans = _matern(dists, nu) * constant  # White: 0 here
        else:
            K_trans = self.kernel_(X, self.X_train_)
        return self._y_train_std * (K_trans @ self.alpha_) + self._y_train_mean

    def _mean_terms(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The fitted kernel's length scales, the scaled training inputs, ν and the constant
        of :meth:`posterior_mean` (Matern's ``__call__`` divides both inputs by the length
        scales each call), kept while the training inputs and these hyperparameters are the
        same objects (setting ``theta`` replaces them)."""
        matern, constant = self.kernel_.k1.k2, self.kernel_.k1.k1.constant_value
        key = (self.X_train_, matern.length_scale, matern.nu, constant)
        terms = getattr(self, "_terms", None)
        if terms is None or any(a is not b for a, b in zip(terms[0], key, strict=True)):
            length_scale = np.squeeze(matern.length_scale).astype(float)
            scaled = (length_scale, self.X_train_ / length_scale, matern.nu, constant)
            terms = self._terms = (key, scaled)
        return terms[1]

    def log_marginal_likelihood(self, theta=None, eval_gradient=False, clone_kernel=True):
        fast = self._searching or (clone_kernel and getattr(self, "fast_likelihood_", False))
        if theta is None or not fast or np.shape(theta) != (self._n_theta,):
            return super().log_marginal_likelihood(theta, eval_gradient, clone_kernel)
        from ._likelihood import matern_likelihood  # numba: loaded by the first fit

        theta = np.asarray(theta, dtype=float)
        y_train = self.y_train_
        if y_train.ndim == 1:
            y_train = y_train[:, np.newaxis]
        n = len(y_train)
        value, gradient, regular = matern_likelihood(
            np.ascontiguousarray(self.X_train_, dtype=float),
            np.ascontiguousarray(y_train, dtype=float),
            theta,
            float(self.kernel_.k1.k2.nu),
            np.array(np.broadcast_to(self.alpha, (n,)), dtype=float),  # writable: one compile
            bool(eval_gradient),
        )
        if not regular:  # scikit-learn's answer where K is not positive definite
            value, gradient = -np.inf, np.zeros_like(theta)
        return (value, gradient) if eval_gradient else value


def _matern(dists: np.ndarray, nu: float) -> np.ndarray:
    """Matérn ν ∈ FAST_NU of scaled distances, as scikit-learn's ``Matern.__call__``."""
    if nu == 1.5:
        K = dists * math.sqrt(3)
        return (1.0 + K) * np.exp(-K)
    K = dists * math.sqrt(5)
    return (1.0 + K + K**2 / 3.0) * np.exp(-K)
