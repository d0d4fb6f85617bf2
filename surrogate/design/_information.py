"""What a candidate test would settle: pure numerics (arrays in, numbers out).

Notations
---------
``F*`` : (A,)
    The calibrated model's curve at the candidate test's conditions [N] (whole degrees
    of the rig's range); ``F_alt`` the curve of an alternative fit at them — a re-fit a
    profile side ended at (:mod:`surrogate.calibration._profile`), a fit the measured
    curves hardly tell from the optimum.
``χ²(alt) = r · Σ (F_alt − F*)² / σ²``
    What ``r`` replicates of the test would add to that fit's RSS over the optimum's, in
    units of the noise variance ``σ²`` (the test's noise has mean zero).
``Δ``
    The profile threshold in the same units (``t²₀.₉₇₅ · s²/σ²``; 3.84 where the misfit is
    the noise).

``χ²_refit(alt)``
    The same once the fit's other parameters re-fit to the test too, the quantity held:
    ``min over d, g·d = 0, x + d in the box`` of ``‖J d‖²/σ² + r‖(F_alt − F*) + S d‖²/σ²``
    (``J`` the measured curves' Jacobian at the alternative, ``S`` the test curve's, both
    in the fit coordinates ``x``; ``g = ∂q/∂x``): the Gauss–Newton model of the profile
    with the test, at the alternative (a constrained optimum of the measured curves, so
    their misfit rises as ``‖J d‖²`` there). A test that rules out the alternative fit but
    not its value of the quantity — the other parameters absorb the difference — closes
    nothing (a 5 mm test tells a coat's Mp, not an Ecoat the curves leave free).

A side of an interval whose alternative sits at ``ρ · Δ`` above the optimum (``ρ ≈ 1``
at a closed end; below 1 at an open side's range end) would sit at ``ρ·Δ + χ²`` with
the test; along the side the profile rises as the square of the step (its
Gauss–Newton model), so the side's end moves in to ``size · √(Δ / (ρΔ + χ²))`` — an
open side closes where ``ρΔ + χ² > Δ``. Two fits (two effects' calibrations) are told
apart by the test where ``χ²`` between their curves exceeds ``SEPARATED`` (two noise
levels of RMS difference over its points and replicates: ``4 · A · r``).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SEPARATED_SD", "added_chi2", "moved_side", "refit_chi2", "separated"]

SEPARATED_SD = 2.0  # two fits are told apart where their curves differ by 2 σ (RMS)


def added_chi2(model_n: np.ndarray, other_n: np.ndarray, noise_n: float, replicates: int) -> float:
    """``χ²`` that ``replicates`` runs of a test add between two fits' curves (A,) [N]."""
    difference = np.asarray(other_n, dtype=float) - np.asarray(model_n, dtype=float)
    return replicates * float(difference @ difference) / noise_n**2


def refit_chi2(
    data_jacobian: np.ndarray,
    test_sensitivity: np.ndarray,
    difference: np.ndarray,
    gradient: np.ndarray,
    box: tuple[np.ndarray, np.ndarray],
    noise_n: float,
    replicates: int,
) -> float:
    """``χ²_refit``: what ``replicates`` runs of a test add at an alternative once the other
    parameters re-fit (linearised, the quantity held: ``gradient·d = 0``).

    ``data_jacobian`` (n, p) ∂r/∂x of the measured curves, ``test_sensitivity`` (A, p) of
    the test's curve, ``difference`` (A,) the alternative's test curve less the optimum's
    [N], ``gradient`` (p,) ∂q/∂x, ``box`` the moves ``d`` allowed (lower, upper)."""
    from scipy.optimize import lsq_linear

    root = math.sqrt(replicates)
    rows = np.vstack([data_jacobian, root * test_sensitivity]) / noise_n
    target = np.concatenate([np.zeros(data_jacobian.shape[0]), -root * difference / noise_n])
    scale = max(float(np.max(np.linalg.norm(rows, axis=0))), 1.0)
    norm = float(np.linalg.norm(gradient))
    if norm > 0:  # the constraint as a row weighted far above every other
        rows = np.vstack([rows, 1e6 * scale * gradient[None, :] / norm])
        target = np.append(target, 0.0)
    lower, upper = box
    move = lsq_linear(rows, target, bounds=(np.minimum(lower, 0.0), np.maximum(upper, 0.0))).x
    misfit = float(np.sum((data_jacobian @ move) ** 2))
    gap = difference + test_sensitivity @ move
    return min(
        (misfit + replicates * float(gap @ gap)) / noise_n**2,
        added_chi2(np.zeros_like(difference), difference, noise_n, replicates),
    )


def moved_side(size: float, ratio: float, chi2: float, threshold: float) -> float | None:
    """A side's new extent (the step ``|q − q*|`` in the quantity's declared scale) with
    the test: ``size · √(Δ / (ρΔ + χ²))`` where that closes or moves it (at most
    ``size``); None where it stays open (``ρΔ + χ² ≤ Δ`` on an open side)."""
    reached = max(ratio, 0.0) * threshold + chi2
    if reached <= threshold:
        return None if ratio < 1.0 else size
    return size * math.sqrt(threshold / reached)


def separated(model_n: np.ndarray, other_n: np.ndarray, noise_n: float, replicates: int) -> bool:
    """Whether the test's ``replicates`` runs tell two fits' curves apart: an RMS
    difference of ``SEPARATED_SD`` noise levels over one run's points, divided by the
    replicates' square root (their mean's scatter)."""
    difference = np.asarray(other_n, dtype=float) - np.asarray(model_n, dtype=float)
    rms = math.sqrt(float(np.mean(difference**2)))
    return rms * math.sqrt(replicates) >= SEPARATED_SD * noise_n
