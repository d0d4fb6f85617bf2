"""The scale curves are modelled on: ``Y = asinh(F/s)`` (numpy only).

Logarithmic for forces well above ``s = FORCE_SCALE_N`` (forces span decades, and
on a log scale a curve is its level plus a shape), linear through zero (a strip
under self-weight that has not yet touched the probe). The calibration's curve
surrogate and the discrepancy between two solvers' curves both live on it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FORCE_SCALE_N", "force_of_latent", "latent_of_force", "latent_slope"]

FORCE_SCALE_N = 0.02


def latent_of_force(force_n: np.ndarray) -> np.ndarray:
    """``asinh(F/s)``."""
    return np.arcsinh(np.asarray(force_n, dtype=float) / FORCE_SCALE_N)


def force_of_latent(latent: np.ndarray) -> np.ndarray:
    """``s·sinh(Y)``: the force [N] of a latent value."""
    return FORCE_SCALE_N * np.sinh(latent)


def latent_slope(latent: np.ndarray) -> np.ndarray:
    """``dF/dY = s·cosh(Y)``: maps a latent standard deviation to newtons."""
    return FORCE_SCALE_N * np.cosh(latent)
