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
    # K = C·M + W + jitter; M = 1 on the diagonal (squared distances and M kept for the gradient)
    K = np.empty((n, n))
    squared = np.empty((n, n))
    M = np.empty((n, n))
    for i in range(n):
        K[i, i] = constant + noise + jitter[i]
        for j in range(i + 1, n):
            squared[i, j] = _squared_distance(scaled, i, j)
            M[i, j] = _matern_value(squared[i, j], nu)
            K[i, j] = K[j, i] = constant * M[i, j]
    L, regular = _cholesky(K)
    if not regular:
        return -np.inf, np.zeros(q), False
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
            gradient[0] += inner * constant * M[i, j]
            slope = inner * constant * _matern_slope(squared[i, j], nu)  # × each (Δx/ℓ)²
            if n_length > 1:
                for k in range(p):
                    step = scaled[i, k] - scaled[j, k]
                    gradient[1 + k] += slope * (step * step)
            else:
                gradient[1] += slope * squared[i, j]
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
def _cholesky(K):  # pragma: no cover - compiled
    """``(L, regular)``: the lower Cholesky factor of ``K``; not ``regular`` where a pivot is
    ≤ 0 or NaN (dpotrf's test).

    Each entry's sum runs in the plain loop's order (``s = K_ij``, then ``s −= L_ik·L_jk``
    for k = 0, 1, …), four rows of a column side by side: the same bits, while the core
    overlaps four sums instead of waiting on one (1.6 × faster at 120 runs)."""
    n = K.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        pivot = K[j, j]
        for k in range(j):
            pivot -= L[j, k] * L[j, k]
        if not pivot > 0.0:
            return L, False
        L[j, j] = math.sqrt(pivot)
        i = j + 1
        while i + 4 <= n:
            s0, s1, s2, s3 = K[i, j], K[i + 1, j], K[i + 2, j], K[i + 3, j]
            for k in range(j):
                b = L[j, k]
                s0 -= L[i, k] * b
                s1 -= L[i + 1, k] * b
                s2 -= L[i + 2, k] * b
                s3 -= L[i + 3, k] * b
            L[i, j], L[i + 1, j] = s0 / L[j, j], s1 / L[j, j]
            L[i + 2, j], L[i + 3, j] = s2 / L[j, j], s3 / L[j, j]
            i += 4
        for row in range(i, n):  # the rows after the groups of four
            s = K[row, j]
            for k in range(j):
                s -= L[row, k] * L[j, k]
            L[row, j] = s / L[j, j]
    return L, True


@njit(cache=True)
def _inverse_from_cholesky(L):  # pragma: no cover - compiled
    """``(L Lᵀ)⁻¹`` from the lower Cholesky factor ``L``.

    ``T = (L⁻¹)ᵀ`` (upper) is held by rows, so both factors of every product are read
    along a row; the sums run in the plain loops' order (k rising from where the
    triangle starts), four of them side by side as in :func:`_cholesky`: the same bits,
    2.3 × faster at 120 runs."""
    n = L.shape[0]
    T = np.zeros((n, n))  # T[j, i] = L⁻¹[i, j]
    for j in range(n):
        T[j, j] = 1.0 / L[j, j]
    for i in range(1, n):  # T[j, i] = −Σ_{k=j}^{i−1} L[i, k]·T[j, k] / L[i, i]
        j = 0
        while j + 4 <= i:
            a0, a1, a2 = L[i, j], L[i, j + 1], L[i, j + 2]  # the sums' first terms, in order
            s0 = s1 = s2 = s3 = 0.0  # from 0.0, as the plain loop: the same sign of a zero
            s0 -= a0 * T[j, j]
            s0 -= a1 * T[j, j + 1]
            s0 -= a2 * T[j, j + 2]
            s1 -= a1 * T[j + 1, j + 1]
            s1 -= a2 * T[j + 1, j + 2]
            s2 -= a2 * T[j + 2, j + 2]
            for k in range(j + 3, i):
                a = L[i, k]
                s0 -= a * T[j, k]
                s1 -= a * T[j + 1, k]
                s2 -= a * T[j + 2, k]
                s3 -= a * T[j + 3, k]
            T[j, i], T[j + 1, i] = s0 / L[i, i], s1 / L[i, i]
            T[j + 2, i], T[j + 3, i] = s2 / L[i, i], s3 / L[i, i]
            j += 4
        for rest in range(j, i):
            s = 0.0
            for k in range(rest, i):
                s -= L[i, k] * T[rest, k]
            T[rest, i] = s / L[i, i]
    inverse = np.empty((n, n))
    for i in range(n):  # inverse[i, j] = Σ_{k=j}^{n−1} T[i, k]·T[j, k], j ≥ i
        j = i
        while j + 4 <= n:
            a0, a1, a2 = T[i, j], T[i, j + 1], T[i, j + 2]
            s0 = s1 = s2 = s3 = 0.0
            s0 += a0 * T[j, j]
            s0 += a1 * T[j, j + 1]
            s0 += a2 * T[j, j + 2]
            s1 += a1 * T[j + 1, j + 1]
            s1 += a2 * T[j + 1, j + 2]
            s2 += a2 * T[j + 2, j + 2]
            for k in range(j + 3, n):
                a = T[i, k]
                s0 += a * T[j, k]
                s1 += a * T[j + 1, k]
                s2 += a * T[j + 2, k]
                s3 += a * T[j + 3, k]
            inverse[i, j] = inverse[j, i] = s0
            inverse[i, j + 1] = inverse[j + 1, i] = s1
            inverse[i, j + 2] = inverse[j + 2, i] = s2
            inverse[i, j + 3] = inverse[j + 3, i] = s3
            j += 4
        for rest in range(j, n):
            s = 0.0
            for k in range(rest, n):
                s += T[i, k] * T[rest, k]
            inverse[i, rest] = inverse[rest, i] = s
    return inverse
