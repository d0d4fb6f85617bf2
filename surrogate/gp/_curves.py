"""GP surrogate of whole force curves over parameters × test conditions (the calibration's).

Notations
---------
X       (n, p) parameter points; ``groups`` (n,) the condition group of each run.
R       (n, f) raw inputs ``features(X, groups)`` — what the solver sees of a test
        (the caller's function; the calibration passes its model-state features).
Z       (n, f') ``R`` scaled to [0, 1] with the ranges of the first fit (columns
        constant there are dropped), so warm-started kernels stay valid.
curves  (n, A) forces [N] on whole degrees from 0°; the 0° column is zero by
        definition and is not modelled.
Y       (n, A − 1) ``asinh(F/s)`` with ``s = FORCE_SCALE_N``: logarithmic for forces
        well above ``s``, linear through zero (a strip under self-weight that has
        not yet touched the probe).

``Y`` is reduced to principal components (:class:`PrincipalBasis`: 99.9999 % of the
variance, at most 16); the scores get a linear trend in ``Z`` (universal kriging,
ridge-stabilised) and one GP each on what the trend leaves (Matérn ν = 2.5, ARD).
Hyperparameters are warm-started from the previous fit.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Literal, overload

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process.kernels import ConstantKernel, Kernel, Matern, WhiteKernel

from ._basis import PrincipalBasis
from ._regressor import Regressor
from ._scale import FORCE_SCALE_N, force_of_latent, latent_of_force, latent_slope

__all__ = ["FORCE_SCALE_N", "CurveSurrogate"]

CURVE_VARIANCE = 1.0 - 1e-6  # share of the transformed curves' variance the basis keeps
MAX_COMPONENTS = 16
TREND_RIDGE = 1e-6  # on the trend's slopes (not its intercept)


class CurveSurrogate:
    """GP of the force curve over the raw inputs ``features(X, groups)``.

    Parameters
    ----------
    features : callable
        ``features(X, groups)`` → (n, f) raw inputs of parameter points ``X`` (n, p)
        at condition groups ``groups`` (n,).
    n_groups : int
        Condition groups ``G``: :meth:`predict` gives every point at every group.
    seed : int
        Seed of the hyperparameter restarts.
    """

    def __init__(
        self,
        features: Callable[[np.ndarray, np.ndarray], np.ndarray],
        n_groups: int,
        *,
        seed: int = 0,
    ) -> None:
        self.features = features
        self.n_groups = n_groups
        self.seed = seed
        self._kernels: list[Kernel] = []
        self._scale: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _inputs(self, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
        raw = self.features(np.atleast_2d(X), groups)
        if self._scale is None:  # fixed at the first fit: warm-started kernels stay valid
            low, high = raw.min(axis=0), raw.max(axis=0)
            keep = high - low > 1e-12 * np.maximum(1.0, np.abs(high))
            self._scale = (keep, low, high)
        keep, low, high = self._scale
        return (raw[:, keep] - low[keep]) / (high[keep] - low[keep])

    def fit(self, X: np.ndarray, groups: np.ndarray, curves: np.ndarray) -> CurveSurrogate:
        """Fit on runs at ``X`` (n, p), ``groups`` (n,) with ``curves`` (n, A)."""
        Z = self._inputs(X, groups)
        Y = latent_of_force(curves[:, 1:])
        self.pca_ = PrincipalBasis.fit(Y, variance=CURVE_VARIANCE, max_components=MAX_COMPONENTS)
        scores = self.pca_.project(Y)
        self.trend_ = self._trend(Z, scores)
        scores = scores - _design(Z) @ self.trend_
        self.gps_ = [self._score_gp(j, Z, scores[:, j]) for j in range(self.pca_.n_components)]
        self._kernels = [gp.kernel_ for gp in self.gps_]
        return self

    @staticmethod
    def _trend(Z: np.ndarray, scores: np.ndarray) -> np.ndarray:
        """Universal kriging: a linear trend in the features (ridge-stabilised)."""
        design = _design(Z)
        ridge = TREND_RIDGE * np.eye(design.shape[1])
        ridge[0, 0] = 0.0
        return np.linalg.solve(design.T @ design + ridge, design.T @ scores)

    def _score_gp(self, j: int, Z: np.ndarray, score: np.ndarray) -> Regressor:
        """The GP of score ``j``, warm-started from the previous fit's kernel if any."""
        warm = j < len(self._kernels)
        gp = Regressor(
            kernel=self._kernels[j] if warm else _kernel(Z.shape[1]),
            normalize_y=True,
            n_restarts_optimizer=0 if warm else 1,
            random_state=self.seed,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp.fit(Z, score)
        return gp

    @overload
    def predict(self, X: np.ndarray, return_std: Literal[False] = False) -> np.ndarray: ...

    @overload
    def predict(
        self, X: np.ndarray, return_std: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def predict(
        self, X: np.ndarray, return_std: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Curves (m, G, A) of every parameter point at every condition group.

        With ``return_std``, also their standard deviation [N] (the scores'
        GPs taken as independent, mapped through the transform's slope).
        """
        X = np.atleast_2d(X)
        m, G = X.shape[0], self.n_groups
        Z = self._inputs(np.repeat(X, G, axis=0), np.tile(np.arange(G), m))
        trend = _design(Z) @ self.trend_
        if return_std:
            pairs = [gp.predict(Z, return_std=True) for gp in self.gps_]
            scores = trend + np.column_stack([p[0] for p in pairs])
            score_var = np.column_stack([p[1] ** 2 for p in pairs])
        else:  # the posterior mean without scikit-learn's per-call checks (the search's hot path)
            scores = trend + np.column_stack([gp.posterior_mean(Z) for gp in self.gps_])
        Y = self.pca_.reconstruct(scores)
        curves = np.zeros((m * G, Y.shape[1] + 1))
        curves[:, 1:] = force_of_latent(Y)
        if not return_std:
            return curves.reshape(m, G, -1)
        std = np.zeros_like(curves)
        std[:, 1:] = latent_slope(Y) * np.sqrt(self.pca_.reconstruct_variance(score_var))
        return curves.reshape(m, G, -1), std.reshape(m, G, -1)


def _design(Z: np.ndarray) -> np.ndarray:
    """The trend's design matrix: an intercept and the features."""
    return np.hstack([np.ones((Z.shape[0], 1)), Z])


def _kernel(n_features: int) -> Kernel:
    length = np.full(n_features, 0.5)
    return ConstantKernel(1.0, (1e-3, 1e3)) * Matern(
        length_scale=length, length_scale_bounds=(1e-2, 1e3), nu=2.5
    ) + WhiteKernel(1e-6, (1e-10, 1e-2))
