"""What the data determine: the identifiable combination and the equally good set.

A single F60 fixes roughly one combination of the three coating parameters.
Locally ``F60 ∝ Π p_k^{a_k}`` with ``a_k = ∂ log F60 / ∂ log p_k`` (from the
surrogate's mean at the chosen point): the combination ``Π p_k^{a_k}`` is
determined, the directions that leave it unchanged are not. The set of equally
good points (verified or predicted within tolerance, feasible) shows how wide
that freedom is; the preferences pick one point from it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Identifiability", "assess_identifiability"]

_SHOWN_EXPONENT = 0.05
_LABELS = {"ecoat_gpa": "Ecoat", "scoat_gpa": "Scoat", "tcoat_mm": "Tcoat"}


@dataclass(frozen=True)
class Identifiability:
    """The identifiability statement of a result (fields are its JSON keys)."""

    exponents: dict[str, float]
    exponents_from: str
    combination: str
    combination_value: float
    relative_uncertainty: float
    set_spread: float
    n_equally_good: int
    ranges: dict[str, list[float]]
    chosen_by: list[str]
    statement: str

    def to_json(self) -> dict[str, object]:
        return asdict(self)


def assess_identifiability(
    names: Sequence[str],
    chosen: np.ndarray,
    log_f60: Callable[[np.ndarray], np.ndarray],
    equally_good: np.ndarray,
    *,
    tolerance: float,
    preference_order: Sequence[str],
    target_n: float,
    solver_gradient: np.ndarray | None = None,
    gradient_source: str | None = None,
) -> Identifiability:
    """Assess what a scalar F60 target determines around ``chosen``.

    Parameters
    ----------
    names : sequence of str
        Parameter names, in column order.
    chosen : ndarray, shape (d,)
        The chosen (verified) point.
    log_f60 : callable
        Surrogate mean of log F60 at points ``(n, d)``.
    equally_good : ndarray, shape (m, d)
        Feasible points whose F60 is within tolerance (verified or predicted).
    solver_gradient : ndarray, shape (d,), optional
        ``∂ log F60 / ∂ log p`` from full-solver runs at ``chosen``; preferred
        to the surrogate's, which is noisy when the surrogate has few points.
    gradient_source : str, optional
        Where ``solver_gradient`` came from, if not from full-solver runs (the
        corrected built-in model of a multi-fidelity study).
    """
    log_chosen = np.log(np.asarray(chosen, dtype=float))
    exponents, scale = _exponents(log_f60, log_chosen, equally_good, solver_gradient)
    shown = [k for k in np.argsort(-np.abs(exponents)) if abs(exponents[k]) >= _SHOWN_EXPONENT]
    combination = " · ".join(f"{_LABELS.get(names[k], names[k])}^{exponents[k]:.2f}" for k in shown)
    value = float(np.exp(exponents @ log_chosen))
    spread, ranges = _equally_good_set(names, chosen, equally_good, exponents)
    # F60 within ±tolerance fixes the combination to ±tolerance / max|a|; the
    # predicted equally good set also shows the surrogate's own scatter.
    uncertainty = tolerance / scale
    source = (
        (gradient_source or "full-solver runs at the result")
        if solver_gradient is not None
        else "the surrogate"
    )
    statement = (
        f"F60 = {target_n:.4g} N ± {100 * tolerance:g} % determines one combination, "
        f"{combination}{_meaning(names, exponents)}, to ±{100 * uncertainty:.1f} % "
        f"(exponents from {source}). The other directions are free: "
        f"{_span(len(equally_good), ranges, spread)}. "
        f"The preferences ({_preferences(preference_order)}) ranked the candidates; the "
        "result is the most preferred verified point that meets the target."
    )
    return Identifiability(
        exponents={n: float(e) for n, e in zip(names, exponents, strict=True)},
        exponents_from=(
            "surrogate"
            if solver_gradient is None
            else "corrected model"
            if gradient_source
            else "full solver"
        ),
        combination=combination,
        combination_value=value,
        relative_uncertainty=float(uncertainty),
        set_spread=float(spread),
        n_equally_good=len(equally_good),
        ranges=ranges,
        chosen_by=list(preference_order),
        statement=statement,
    )


def _exponents(
    log_f60: Callable[[np.ndarray], np.ndarray],
    log_chosen: np.ndarray,
    equally_good: np.ndarray,
    solver_gradient: np.ndarray | None,
) -> tuple[np.ndarray, float]:
    """The exponents ``a_k`` scaled to max |a| = 1, and the scale max |∂ log F60 / ∂ log p|."""
    if solver_gradient is not None:
        mean = np.asarray(solver_gradient, dtype=float)
        scale = float(np.max(np.abs(mean))) or 1.0
    else:
        # Average the surrogate's local exponents over the equally good set:
        # one point's gradient of a sparse surrogate is noisy, the set's mean less so.
        sites = (
            np.vstack([log_chosen, np.log(np.atleast_2d(equally_good))])
            if len(equally_good)
            else log_chosen[None, :]
        )
        gradients = _log_gradients(log_f60, sites)
        scales = np.max(np.abs(gradients), axis=1, keepdims=True)
        mean = np.mean(gradients / np.where(scales > 0, scales, 1.0), axis=0)
        scale = float(np.median(scales))
    return mean / (float(np.max(np.abs(mean))) or 1.0), scale


def _equally_good_set(
    names: Sequence[str], chosen: np.ndarray, equally_good: np.ndarray, exponents: np.ndarray
) -> tuple[float, dict[str, list[float]]]:
    """The relative spread of the combination over the equally good set, and its ranges."""
    if not len(equally_good):
        return float("nan"), {n: [float(chosen[k]), float(chosen[k])] for k, n in enumerate(names)}
    points = np.atleast_2d(equally_good)
    combos = np.log(points) @ exponents
    spread = float(np.exp((combos.max() - combos.min()) / 2.0) - 1.0)
    ranges = {
        n: [float(points[:, k].min()), float(points[:, k].max())] for k, n in enumerate(names)
    }
    return spread, ranges


def _log_gradients(
    log_f60: Callable[[np.ndarray], np.ndarray], sites: np.ndarray, step: float = 1e-3
) -> np.ndarray:
    """Central differences of log F60 in log parameters at every site, (m, d)."""
    m, d = sites.shape
    shifts = np.vstack([np.eye(d) * step, -np.eye(d) * step])  # (2d, d)
    values = log_f60(np.exp((sites[:, None, :] + shifts[None, :, :]).reshape(-1, d)))
    values = values.reshape(m, 2 * d)
    return (values[:, :d] - values[:, d:]) / (2 * step)


def _meaning(names: Sequence[str], exponents: np.ndarray) -> str:
    index = {n: k for k, n in enumerate(names)}
    if not all(n in index for n in _LABELS):
        return ""
    e, s, t = (abs(exponents[index[n]]) for n in ("ecoat_gpa", "scoat_gpa", "tcoat_mm"))
    if e > 0.7 and t > 0.7 and s < 0.3:
        return " (≈ the bending stiffness, D ∝ Ecoat·Tcoat)"
    if s > 0.7 and t > 0.7 and e < 0.3:
        return " (≈ the plastic moment, Mp ∝ Scoat·Tcoat)"
    return ""


def _span(n_good: int, ranges: dict[str, list[float]], spread: float) -> str:
    if n_good == 0:
        return "no other equally good point was found"
    span = ", ".join(f"{_LABELS.get(n, n)} {lo:.3g}–{hi:.3g}" for n, (lo, hi) in ranges.items())
    return (
        f"{n_good} equally good points (verified or predicted) span {span}, the "
        f"combination scattering ±{100 * spread:.0f} % over them"
    )


def _preferences(order: Sequence[str]) -> str:
    return ", then ".join(f"lower {_LABELS.get(n, n)}" for n in order) or "none"
