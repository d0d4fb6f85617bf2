"""Statistics of a misfit against the measurement noise (pure: numbers in, numbers out).

One place for the tests that the calibration's status and the diagnosis share:
"is this residual what the noise explains?" and the information criterion that
ranks models.
"""

from __future__ import annotations

import math

from scipy import stats

__all__ = ["SIGNIFICANCE", "bic", "misfit_p_value", "noise_dof"]

SIGNIFICANCE = 0.01  # family-wise level of every test (Bonferroni within a family)


def misfit_p_value(rss: float, dof: int, noise: float, dof_noise: float) -> float:
    """P-value of "the residuals are noise": ``(RSS/dof)/s² ~ F(dof, dof_noise)``.

    Parameters
    ----------
    rss : float
        Residual sum of squares [N²].
    dof : int
        Its degrees of freedom (points − fitted parameters).
    noise : float
        The noise level ``s`` [N].
    dof_noise : float
        Degrees of freedom of ``s`` (replicates); ``inf`` for a stated noise level
        (then the test is χ²).
    """
    if dof <= 0:
        return 1.0
    ratio = rss / dof / noise**2
    if math.isinf(dof_noise):
        return float(stats.chi2.sf(ratio * dof, dof))
    return float(stats.f.sf(ratio, dof, dof_noise))


def noise_dof(stated: bool, replicate_dof: int) -> float:
    """Degrees of freedom of the noise level: ``inf`` when stated in the study
    (``[measurements] noise_n``) or unknown, else the replicates'."""
    return math.inf if stated or not replicate_dof else float(replicate_dof)


def bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a least-squares fit with ``k`` parameters."""
    return n * math.log(rss / n) + k * math.log(n)
