"""Features of a force–rotation curve: the one place that defines them.

Used alike for solver output, surrogate training and measured curves.

- ``F60``: force at 60° of fixture rotation (linear interpolation).
- ``theta_sat``: the first rotation at which the secant slope over the
  following 5° falls below 10 % of the initial slope (secant 0→10°), on a 1°
  grid. If that never happens within the tested range, ``theta_sat`` is the
  range end and the curve is marked not saturated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputDataError

__all__ = ["F60_ANGLE_DEG", "CurveFeatures", "curve_features"]

F60_ANGLE_DEG = 60.0
_SECANT_SPAN_DEG = 5
_INITIAL_SPAN_DEG = 10
_SATURATION_FRACTION = 0.10


@dataclass(frozen=True)
class CurveFeatures:
    """``f60_n`` [N] (NaN if the curve ends before 60°), ``theta_sat_deg``, ``saturated``."""

    f60_n: float
    theta_sat_deg: float
    saturated: bool


def curve_features(angle_deg: np.ndarray, force_n: np.ndarray) -> CurveFeatures:
    """F60 and the saturation angle of one curve.

    Parameters
    ----------
    angle_deg : array_like, shape (n,)
        Strictly increasing rotations [deg]; a curve that does not start at 0°
        is taken to start from zero force at 0° (the test has no preload).
    force_n : array_like, shape (n,)
        Force at each angle [N].
    """
    angle = np.asarray(angle_deg, dtype=float)
    force = np.asarray(force_n, dtype=float)
    if angle.shape != force.shape or angle.ndim != 1 or angle.size < 2:
        raise InputDataError(
            f"a curve needs two 1-D arrays of equal length ≥ 2, got shapes "
            f"{angle.shape} and {force.shape}"
        )
    if not (np.all(np.isfinite(angle)) and np.all(np.isfinite(force))):
        raise InputDataError("a curve contains NaN or inf; remove or fix those points")
    if np.any(np.diff(angle) <= 0.0):
        raise InputDataError("curve angles must be strictly increasing; sort the points")
    if angle[0] > 0.0:
        angle = np.concatenate(([0.0], angle))
        force = np.concatenate(([0.0], force))
    end = float(angle[-1])
    f60 = float(np.interp(F60_ANGLE_DEG, angle, force)) if end >= F60_ANGLE_DEG else np.nan
    grid = np.arange(0.0, np.floor(end) + 1.0)
    on_grid = np.interp(grid, angle, force)
    if grid.size <= _INITIAL_SPAN_DEG:
        return CurveFeatures(f60, end, False)
    initial_slope = (on_grid[_INITIAL_SPAN_DEG] - on_grid[0]) / _INITIAL_SPAN_DEG
    secant = (on_grid[_SECANT_SPAN_DEG:] - on_grid[:-_SECANT_SPAN_DEG]) / _SECANT_SPAN_DEG
    below = np.nonzero(secant < _SATURATION_FRACTION * initial_slope)[0]
    if below.size == 0:
        return CurveFeatures(f60, end, False)
    return CurveFeatures(f60, float(grid[below[0]]), True)
