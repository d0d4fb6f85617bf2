"""The log-marginal likelihood of ``C · Matern(ν, ARD) + White`` and its gradient, compiled.

One call computes what scikit-learn's ``GaussianProcessRegressor.log_marginal_likelihood``
computes for that kernel (its definitions, its order of terms), in loops instead of some
thirty small array operations: on the product's 8–120 runs the operations' cost per call,
not the arithmetic, had set the pace of every hyperparameter fit. The Cholesky factor,
the solves and the inverse are loops here too, so the numbers do not depend on the BLAS
library or its kernels; they differ from scikit-learn's by rounding only
(``tests/gp/test_regressor.py``).

Compiled by numba on first use (cached next to the sources, as the rod's kernels), and
imported only by a fit's hyperparameter search: ``import surrogate`` does not load numba.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["matern_likelihood"]


@njit(cache=True)
def matern_likelihood(X, Y, theta, nu, jitter, eval_gradient):  # pragma: no cover - compiled
    """``(value, gradient, regular)`` at log-hyperparameters ``theta``.

    ``X`` (n, p) training inputs, ``Y`` (n, m) training targets (normalised as the
    regressor holds them), ``theta`` = log [C, length scale(s), noise level] (one length
    scale: isotropic), ``nu`` 1.5 or 2.5, ``jitter`` (n,) the regressor's ``alpha`` on the
    diagonal. ``regular`` is False where ``K`` is not positive definite (value and
    gradient are then meaningless); the gradient is zero unless ``eval_gradient``.
    """
    n, p = X.shape
    m = Y.shape[1]
    q = theta.size
    n_length = q - 2
    constant = math.exp(theta[0])
    noise = math.exp(theta[q - 1])
    scaled = np.empty((n, p))
    for k in range(p):
        length = math.exp(theta[1 + k]) if n_length > 1 else math.exp(theta[1])
        for i in range(n):
            scaled[i, k] = X[i, k] / length
    # K = C·M + W + jitter; M = 1 on the diagonal
    K = np.empty((n, n))
    for i in range(n):
        K[i, i] = constant + noise + jitter[i]
        for j in range(i + 1, n):
            K[i, j] = K[j, i] = constant * _matern_value(_squared_distance(scaled, i, j), nu)
    L = np.zeros((n, n))
    for j in range(n):  # Cholesky, lower: dpotrf's test for a pivot ≤ 0 or NaN
        pivot = K[j, j]
        for k in range(j):
            pivot -= L[j, k] * L[j, k]
        if not pivot > 0.0:
            return -np.inf, np.zeros(q), False
        L[j, j] = math.sqrt(pivot)
        for i in range(j + 1, n):
            s = K[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    alpha = np.empty((n, m))  # K⁻¹ Y
    for c in range(m):
        for i in range(n):
            s = Y[i, c]
            for k in range(i):
                s -= L[i, k] * alpha[k, c]
            alpha[i, c] = s / L[i, i]
        for i in range(n - 1, -1, -1):
            s = alpha[i, c]
            for k in range(i + 1, n):
                s -= L[k, i] * alpha[k, c]
            alpha[i, c] = s / L[i, i]
    log_det = 0.0
    for i in range(n):
        log_det += math.log(L[i, i])
    value = 0.0
    for c in range(m):  # each output's term, as scikit-learn sums them
        fit = 0.0
        for i in range(n):
            fit += Y[i, c] * alpha[i, c]
        value += -0.5 * fit - log_det - n / 2 * math.log(2 * math.pi)
    gradient = np.zeros(q)
    if not eval_gradient:
        return value, gradient, True
    inverse = _inverse_from_cholesky(L)
    # ∂/∂θ = ½ Σ_ij (Σ_c α_ic α_jc − m K⁻¹_ij) ∂K_ij/∂θ, K symmetric: twice the upper half
    for i in range(n):
        inner = -m * inverse[i, i]
        for c in range(m):
            inner += alpha[i, c] * alpha[i, c]
        gradient[0] += 0.5 * inner * constant  # ∂K_ii/∂log C = C (M_ii = 1)
        gradient[q - 1] += 0.5 * inner * noise
        for j in range(i + 1, n):
            inner = -m * inverse[i, j]
            for c in range(m):
                inner += alpha[i, c] * alpha[j, c]
            squared = _squared_distance(scaled, i, j)
            gradient[0] += inner * constant * _matern_value(squared, nu)
            slope = inner * constant * _matern_slope(squared, nu)  # × each (Δx/ℓ)²
            if n_length > 1:
                for k in range(p):
                    step = scaled[i, k] - scaled[j, k]
                    gradient[1 + k] += slope * (step * step)
            else:
                gradient[1] += slope * squared
    return value, gradient, True


@njit(cache=True)
def _squared_distance(scaled, i, j):  # pragma: no cover - compiled
    total = 0.0
    for k in range(scaled.shape[1]):
        step = scaled[i, k] - scaled[j, k]
        total += step * step
    return total


@njit(cache=True)
def _matern_value(squared, nu):  # pragma: no cover - compiled
    """Matérn ν ∈ {1.5, 2.5} at a squared scaled distance (scikit-learn's formulas)."""
    if nu == 1.5:
        scaled = math.sqrt(squared) * math.sqrt(3.0)
        return (1.0 + scaled) * math.exp(-scaled)
    scaled = math.sqrt(squared) * math.sqrt(5.0)
    return (1.0 + scaled + scaled * scaled / 3.0) * math.exp(-scaled)


@njit(cache=True)
def _matern_slope(squared, nu):  # pragma: no cover - compiled
    """∂M/∂log ℓ_k divided by (Δx_k/ℓ_k)² (scikit-learn's Matern gradient)."""
    if nu == 1.5:
        return 3.0 * math.exp(-math.sqrt(3.0 * squared))
    scaled = math.sqrt(5.0 * squared)
    return 5.0 / 3.0 * (scaled + 1.0) * math.exp(-scaled)


@njit(cache=True)
def _inverse_from_cholesky(L):  # pragma: no cover - compiled
    """``(L Lᵀ)⁻¹`` from the lower Cholesky factor ``L``."""
    n = L.shape[0]
    inv_l = np.zeros((n, n))  # L⁻¹, lower
    for j in range(n):
        inv_l[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * inv_l[k, j]
            inv_l[i, j] = s / L[i, i]
    inverse = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(j, n):
                s += inv_l[k, i] * inv_l[k, j]
            inverse[i, j] = inverse[j, i] = s
    return inverse
