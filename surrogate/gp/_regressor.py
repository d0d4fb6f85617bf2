"""scikit-learn's Gaussian process regressor with a fast log-marginal likelihood.

Both of the product's GPs (:mod:`._output`, :mod:`._curves`) use the kernel
``C · Matern(ν, ARD) + White`` and fit its hyperparameters by L-BFGS-B on
scikit-learn's log-marginal likelihood: about 30 evaluations a fit, hundreds of fits
a calibration. Each evaluation sets ``kernel.theta`` and calls the composed kernel,
and that bookkeeping (``get_params``, ``dir``, cloning of hyperparameter objects)
outweighed the arithmetic on the product's tens of runs (``benchmarks/gp_fit.py``:
fits 1.3–2.4 × and posterior means of a search batch 4.4–7 × faster, 10–80 runs).

:class:`Regressor` evaluates the likelihood of that one kernel from ``theta``
directly, with the same arithmetic as scikit-learn 1.9
(``GaussianProcessRegressor.log_marginal_likelihood`` and the kernels' ``__call__``):
each number is computed by the same operations in the same order, though the
gradient's arrays are laid out a length scale at a time, so the value and its
gradient are the same numbers, bit for bit (``tests/gp/test_regressor.py`` checks
this against scikit-learn's own on random kernels and data, with 1 to 9 features).
Where scikit-learn's would set the kernel's ``theta`` as a side effect, only inside
``fit``'s search is that skipped (its end sets it); any other kernel, or call, goes
to scikit-learn's implementation unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs
from scipy.spatial.distance import cdist, pdist, squareform
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
    likelihood is the same to the last bit); only its evaluation during ``fit`` is faster.
    The fast likelihood is taken where scikit-learn's leaves the kernel as it is
    (``clone_kernel=True``) and inside ``fit``'s hyperparameter search, whose end sets the
    kernel's ``theta`` anyway. A fit without optimizer keeps scikit-learn's path: there,
    setting ``theta`` rounds each hyperparameter through ``exp(log(·))``, and the fit's
    matrices follow from the rounded values.
    """

    _searching = False  # inside fit's hyperparameter search

    def fit(self, X, y):
        fast = _fast_form(self.kernel)
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
        theta = np.asarray(theta)
        K, K_gradient = _kernel_matrix(self.kernel_.k1.k2.nu, self.X_train_, theta, eval_gradient)
        K.flat[:: K.shape[0] + 1] += self.alpha  # the diagonal, as scikit-learn's index
        L, info = dpotrf(K, lower=1, clean=1)  # scipy.linalg.cholesky's LAPACK call
        if info > 0:
            return (-np.inf, np.zeros_like(theta)) if eval_gradient else -np.inf
        y_train = self.y_train_
        if y_train.ndim == 1:
            y_train = y_train[:, np.newaxis]
        alpha, _ = dpotrs(L, y_train, lower=1)  # scipy.linalg.cho_solve's
        log_likelihood_dims = -0.5 * np.einsum("ik,ik->k", y_train, alpha)
        log_likelihood_dims -= np.log(np.diag(L)).sum()
        log_likelihood_dims -= K.shape[0] / 2 * np.log(2 * np.pi)
        log_likelihood = log_likelihood_dims.sum(axis=-1)
        if not eval_gradient:
            return log_likelihood
        inner_term = np.einsum("ik,jk->ijk", alpha, alpha)
        K_inv, _ = dpotrs(L, np.eye(K.shape[0]), lower=1)
        inner_term -= K_inv[..., np.newaxis]
        gradient_dims = 0.5 * np.einsum("ijl,jik->kl", inner_term, K_gradient)
        return log_likelihood, gradient_dims.sum(axis=-1)


def _kernel_matrix(
    nu: float, X: np.ndarray, theta: np.ndarray, eval_gradient: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """``C · Matern(nu) + White`` at ``X`` for log-hyperparameters ``theta``.

    ``theta`` = log [C, length scale(s), noise level], the kernel's own order. The
    numbers are scikit-learn's: ``C · M`` is the same product taken either way round,
    and its ``+ W`` adds zero off the diagonal, so only the diagonal gets the noise here.
    """
    n_length = len(theta) - 2
    constant = np.exp(theta[0])
    length = np.exp(theta[1 : 1 + n_length]) if n_length > 1 else np.exp(theta[1])
    noise = np.exp(theta[-1])
    length_scale = np.squeeze(length).astype(float)  # Matern's _check_length_scale
    X = np.atleast_2d(X)
    n = X.shape[0]
    dists = pdist(X / length_scale, metric="euclidean")
    M = squareform(_matern(dists, nu))
    M.flat[:: n + 1] = 1  # fill_diagonal
    CM = M * constant
    K = CM.copy()
    K.flat[:: n + 1] += noise
    if not eval_gradient:
        return K, None
    # The gradient by length scale: scikit-learn's element-wise operations in its order,
    # on one contiguous n × n plane a length scale instead of its n × n × p array (on
    # hundreds of runs several times faster; the same numbers).
    if n_length > 1:  # anisotropic: (X_ik − X_jk)² / ℓ_k²
        planes = np.empty((n_length, n, n))
        for k in range(n_length):
            np.subtract(X[:, k, np.newaxis], X[np.newaxis, :, k], out=planes[k])
        np.square(planes, out=planes)
        planes /= (length_scale**2)[:, np.newaxis, np.newaxis]
        D_sum = _sum_over_length_scales(planes)
    else:
        D_sum = squareform(dists**2)
        planes = D_sum[np.newaxis].copy()
    if nu == 1.5:
        planes *= 3
        planes *= np.exp(-np.sqrt(3 * D_sum))
    else:
        tmp = np.sqrt(5 * D_sum)
        planes *= 5.0 / 3.0
        planes *= tmp + 1
        planes *= np.exp(-tmp)
    K_gradient = np.zeros((n, n, len(theta)))
    K_gradient[:, :, 0] = CM
    for k, plane in enumerate(planes):
        np.multiply(plane, constant, out=K_gradient[:, :, 1 + k])
    K_gradient[np.arange(n), np.arange(n), -1] = noise
    return K, K_gradient


def _sum_over_length_scales(planes: np.ndarray) -> np.ndarray:
    """``D.sum(-1)`` of scikit-learn's n × n × p array ``D`` whose planes are ``planes``:
    NumPy adds a contiguous last axis of fewer than 8 in order (``tests/gp``'s
    dimensions check it), a longer one pairwise, which only ``D`` itself repeats."""
    if len(planes) >= 8:
        return np.ascontiguousarray(np.moveaxis(planes, 0, -1)).sum(-1)
    total = planes[0].copy()
    for plane in planes[1:]:
        total += plane
    return total


def _matern(dists: np.ndarray, nu: float) -> np.ndarray:
    """Matérn ν ∈ FAST_NU of scaled distances, as scikit-learn's ``Matern.__call__``."""
    if nu == 1.5:
        K = dists * math.sqrt(3)
        return (1.0 + K) * np.exp(-K)
    K = dists * math.sqrt(5)
    return (1.0 + K + K**2 / 3.0) * np.exp(-K)
