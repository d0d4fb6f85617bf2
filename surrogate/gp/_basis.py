"""A reduced basis of curves: principal components of the training curves.

Notations
---------
Y       (n, m) transformed training curves (one row per run, one column per angle).
mean    (m,) their column means; the basis is fitted to ``Y − mean``.
basis   (k, m) the first ``k`` right singular vectors of ``Y − mean`` (orthonormal rows).
scores  (n, k) ``(Y − mean) @ basisᵀ``; a curve is reconstructed as ``mean + scores @ basis``.

``k`` is the fewest components whose share of the variance reaches ``variance``,
at most ``max_components`` (and at most the rank the data allow). Both curve
surrogates (:class:`~surrogate.gp.CoatingSurrogate`'s log-curves and
:class:`~surrogate.gp.CurveSurrogate`'s ``asinh`` curves) use this one basis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PrincipalBasis"]


@dataclass(frozen=True)
class PrincipalBasis:
    """Centre, SVD, keep ``k`` components; project curves to scores and back."""

    mean: np.ndarray
    basis: np.ndarray

    @classmethod
    def fit(cls, Y: np.ndarray, *, variance: float, max_components: int) -> PrincipalBasis:
        """The basis of ``Y`` (n, m) keeping a share ``variance`` of its variance."""
        mean = Y.mean(axis=0)
        _, singular, basis = np.linalg.svd(Y - mean, full_matrices=False)
        explained = np.cumsum(singular**2) / max(float(np.sum(singular**2)), 1e-300)
        k = int(min(np.searchsorted(explained, variance) + 1, basis.shape[0], max_components))
        return cls(mean, basis[:k])

    @property
    def n_components(self) -> int:
        return int(self.basis.shape[0])

    def project(self, Y: np.ndarray) -> np.ndarray:
        """Scores (n, k) of curves ``Y`` (n, m)."""
        return (Y - self.mean) @ self.basis.T

    def reconstruct(self, scores: np.ndarray) -> np.ndarray:
        """Curves (n, m) of scores (n, k)."""
        return self.mean + scores @ self.basis

    def reconstruct_variance(self, score_variance: np.ndarray) -> np.ndarray:
        """Variance (n, m) of the reconstructed curves for independent scores of variance
        ``score_variance`` (n, k)."""
        return score_variance @ self.basis**2
