"""The discrepancy between two fidelities, learned from a few expensive runs.

Kennedy & O'Hagan's (2000) autoregressive model, ``y_hi(z) = ρ·y_lo(z) + δ(z)``, taken
on a logarithmic scale: the caller passes ``D = Y_hi − Y_lo`` with ``Y`` the log (or
asinh) of the response, so ``ρ = 1`` and a constant scale factor between the solvers
is the GP's constant mean ``μ``; ``δ`` is a zero-mean GP around it. Both solvers model
the same test, so the low-fidelity response carries the shape and ``δ`` only what
they disagree on.

Notations
---------
Z      (n, k) inputs of the expensive runs, in units of the span over which the
       response typically changes (the caller scales them).
D      (n, m) discrepancies at ``Z``: ``m`` outputs (a scalar feature: ``m = 1``; a curve:
       one output per angle) sharing one kernel.
R      (n, n) correlation of ``Z``, one kernel for every output: a Matérn 5/2 of one length
       scale ``ℓ`` plus a linear part ``c·(z − z̄)ᵀ(z' − z̄)`` (``z̄`` the runs' mean
       input: a slope in each input, of prior standard deviation ``√c`` amplitudes per
       unit — a discrepancy that follows one input and not the others needs no length
       scale per input), with the nugget ``g`` (noise over amplitude) on its diagonal.
μ      (m,) constant mean of each output by generalised least squares,
       ``(1ᵀR⁻¹D)/(1ᵀR⁻¹1)``: with one run, that run's discrepancy.
s²     (m,) amplitude of each output: the prior ``s₀²`` worth ``PRIOR_RUNS`` runs,
       updated by the runs' own scatter (the conjugate inverse-χ² update),
       ``(PRIOR_RUNS·s₀² + (D − μ)ᵀR⁻¹(D − μ)) / (PRIOR_RUNS + n − 1)``.

At ``z``, with ``r`` its correlation to ``Z``: mean ``μ + rᵀR⁻¹(D − μ)``, variance
``s²·(1 + g − rᵀR⁻¹r + (1 − 1ᵀR⁻¹r)² / 1ᵀR⁻¹1)`` (ordinary kriging: the uncertainty of
``μ`` included, so far from every run the variance is the prior's, not zero).

``ℓ``, ``c`` and ``g`` are fixed (``LENGTH_SCALE``, ``SLOPE``; the nugget of the caller's
``noise_sd``) until ``SELECT_FROM`` runs; from then on they are those of a small grid
with the largest restricted likelihood, summed over the outputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.distance import cdist

__all__ = ["Discrepancy"]

LENGTH_SCALE = 1.0  # the input span over which the discrepancy may change by its amplitude
SLOPE = 1.0  # prior variance of its slope in each input, in amplitudes² per unit²
PRIOR_RUNS = 2.0  # weight of the prior amplitude, in runs
SELECT_FROM = 4  # runs from which ℓ and g are chosen by restricted likelihood
LENGTH_GRID = (0.25, 0.5, 1.0, 2.0, 4.0)
SLOPE_GRID = (0.0, 0.25, 1.0, 4.0)
NUGGET_GRID = (1e-4, 1e-2, 1e-1)  # above the caller's noise: a rough discrepancy
_JITTER = 1e-10


@dataclass(frozen=True)
class _Kernel:
    """Matérn 5/2 of length ``length`` plus ``slope·(a − centre)ᵀ(b − centre)``."""

    length: float
    slope: float
    centre: np.ndarray

    def __call__(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        r = np.sqrt(5.0) * cdist(A, B) / self.length
        linear = self.slope * (A - self.centre) @ (B - self.centre).T
        return (1.0 + r + r**2 / 3.0) * np.exp(-r) + linear


@dataclass(frozen=True)
class _Fitted:
    Z: np.ndarray
    kernel: _Kernel
    nugget: float
    factor: tuple[np.ndarray, bool]
    ones: np.ndarray  # R⁻¹1
    ones_sum: float  # 1ᵀR⁻¹1
    mean: np.ndarray  # μ (m,)
    alpha: np.ndarray  # R⁻¹(D − μ) (n, m)
    amplitude: np.ndarray  # s (m,)
    scale: np.ndarray  # the runs' own amplitude, (D − μ)ᵀR⁻¹(D − μ)/(n − 1) (m,), its square root


class Discrepancy:
    """δ(z): a GP of ``m`` outputs with constant means and one shared kernel.

    Parameters
    ----------
    prior_sd : float or array of shape (m,)
        Amplitude ``s₀`` before any run: how far the solvers may disagree [the
        outputs' units]. Also the standard deviation of a prediction before any run.
    noise_sd : float or array of shape (m,)
        What the expensive solver itself scatters by (its discretisation); sets the
        smallest nugget.
    """

    def __init__(self, prior_sd: float | np.ndarray, *, noise_sd: float | np.ndarray) -> None:
        self.prior_sd = np.atleast_1d(np.asarray(prior_sd, dtype=float))
        self.noise_sd = np.atleast_1d(np.asarray(noise_sd, dtype=float))
        self._fitted: _Fitted | None = None

    @property
    def n_runs(self) -> int:
        return 0 if self._fitted is None else int(self._fitted.Z.shape[0])

    @property
    def length_scale(self) -> float:
        return LENGTH_SCALE if self._fitted is None else self._fitted.kernel.length

    @property
    def slope(self) -> float:
        return SLOPE if self._fitted is None else self._fitted.kernel.slope

    @property
    def nugget(self) -> float:
        return self._min_nugget() if self._fitted is None else self._fitted.nugget

    @property
    def scatter(self) -> np.ndarray:
        """What the fit attributes to noise, per output (m,): ``σ̂·√g`` with ``σ̂`` the runs'
        own amplitude (the restricted-likelihood estimate, no prior in it), so runs that
        hardly differ are not called noisy by a prior amplitude — the nugget being the
        likelihood's choice from ``SELECT_FROM`` runs on."""
        if self._fitted is None:
            return self.noise_sd * np.ones_like(self.prior_sd)
        return self._fitted.scale * np.sqrt(self._fitted.nugget)

    @property
    def selected(self) -> bool:
        """Whether ``ℓ`` and ``g`` were chosen by the runs' likelihood."""
        return self.n_runs >= SELECT_FROM

    def _min_nugget(self) -> float:
        return float(np.max((self.noise_sd / self.prior_sd) ** 2)) + _JITTER

    def fit(self, Z: np.ndarray, D: np.ndarray) -> Discrepancy:
        """Learn from ``n ≥ 1`` runs: inputs ``Z`` (n, k), discrepancies ``D`` (n, m)."""
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        D = np.asarray(D, dtype=float).reshape(Z.shape[0], -1)
        if Z.shape[0] == 0 or not np.all(np.isfinite(D)) or not np.all(np.isfinite(Z)):
            raise ValueError("a discrepancy needs at least one run with finite inputs and values")
        centre = Z.mean(axis=0)
        choices = [(_Kernel(LENGTH_SCALE, SLOPE, centre), self._min_nugget())]
        if Z.shape[0] >= SELECT_FROM:
            nuggets = sorted({self._min_nugget(), *NUGGET_GRID})
            choices = [
                (_Kernel(length, slope, centre), g)
                for length in LENGTH_GRID
                for slope in SLOPE_GRID
                for g in nuggets
            ]
        fits = [self._fit(Z, D, kernel, g) for kernel, g in choices]
        self._fitted = max(fits, key=lambda item: item[1])[0]
        return self

    def _fit(
        self, Z: np.ndarray, D: np.ndarray, kernel: _Kernel, g: float
    ) -> tuple[_Fitted, float]:
        """The fit with ``kernel`` and nugget ``g``, and its restricted log-likelihood
        (amplitudes profiled)."""
        n = Z.shape[0]
        R = kernel(Z, Z) + g * np.eye(n)
        factor = cho_factor(R, lower=True)
        ones = cho_solve(factor, np.ones(n))
        ones_sum = float(np.sum(ones))
        mean = ones @ D / ones_sum
        centred = D - mean
        alpha = cho_solve(factor, centred)
        quad = np.sum(centred * alpha, axis=0)  # (m,)
        amplitude = np.sqrt((PRIOR_RUNS * self.prior_sd**2 + quad) / (PRIOR_RUNS + n - 1))
        scale = np.sqrt(quad / max(n - 1, 1))
        log_det = 2.0 * float(np.sum(np.log(np.diag(factor[0]))))
        if n > 1:
            sigma2 = np.maximum(quad / (n - 1), 1e-300)
            loglik = -0.5 * float(np.sum((n - 1) * np.log(sigma2) + log_det + np.log(ones_sum)))
        else:
            loglik = 0.0
        fitted = _Fitted(Z, kernel, g, factor, ones, ones_sum, mean, alpha, amplitude, scale)
        return fitted, loglik

    def predict(
        self, Z: np.ndarray, return_std: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Mean (n', m) at ``Z`` (n', k), and with ``return_std`` its standard deviation
        (n', m). Before any run: zero mean, the prior's standard deviation."""
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        fitted = self._fitted
        if fitted is None:
            m = max(self.prior_sd.size, self.noise_sd.size)
            mean = np.zeros((Z.shape[0], m))
            std = np.broadcast_to(self.prior_sd, mean.shape).copy()
            return (mean, std) if return_std else mean
        r = fitted.kernel(Z, fitted.Z)  # (n', n)
        mean = fitted.mean + r @ fitted.alpha
        if not return_std:
            return mean
        solved = cho_solve(fitted.factor, r.T)  # (n, n')
        explained = np.sum(r.T * solved, axis=0)
        unexplained_mean = (1.0 - r @ fitted.ones) ** 2 / fitted.ones_sum
        prior = self._prior(Z)
        share = np.maximum(prior + fitted.nugget - explained + unexplained_mean, 0.0)
        return mean, np.sqrt(share)[:, None] * fitted.amplitude[None, :]

    def _prior(self, Z: np.ndarray) -> np.ndarray:
        """The kernel's variance at each of ``Z`` (its diagonal, without the n'² matrix)."""
        assert self._fitted is not None
        kernel = self._fitted.kernel
        return 1.0 + kernel.slope * np.sum((Z - kernel.centre) ** 2, axis=1)
