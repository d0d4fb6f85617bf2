"""What the data determine: the identifiable combination and the equally good set.

A single F60 fixes roughly one combination of the three coating parameters.
Locally ``F60 ∝ Π p_k^{a_k}`` with ``a_k = ∂ log F60 / ∂ log p_k`` (from the
solver's runs at the chosen point, else the surrogate's mean): the combination
``Π p_k^{a_k}`` is determined, the directions that leave it unchanged are not.

That is a linear statement, true near the chosen point. The set of equally good
points (verified or predicted within tolerance, feasible) checks it: where the
combination scatters over the set by more than ``LINEAR_HOLDS`` times the linear
``±tolerance / max|a|``, F60 depends on other things elsewhere in the ranges (a coat
whose curve saturates before 60° is set by its plastic moment, not by D), and the
statement says the linear figure holds near the result only. Each parameter's span
over the set says which sides the target leaves open: a side the set reaches within
``OPEN_UNIT`` of the declared bound is not bounded by the target (``kinds``: the
calibration's words, two-sided, lower-bound, upper-bound, free). The set is what the
search found, so a span is at least that wide; the predicted points are the
surrogate's, not run. The preferences pick one point from it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["Identifiability", "assess_identifiability"]

_SHOWN_EXPONENT = 0.05
LINEAR_HOLDS = 1.5  # the set's scatter of the combination within this × the linear ±: it holds
OPEN_UNIT = 0.02  # a span this near a bound (share of its range, log where declared) reaches it
_LABELS = {"ecoat_gpa": "Ecoat", "scoat_gpa": "Scoat", "tcoat_mm": "Tcoat"}


@dataclass(frozen=True)
class Identifiability:
    """The identifiability statement of a result (fields are its JSON keys).

    ``relative_uncertainty`` is the linear ± of the combination; ``set_spread`` its
    scatter over the ``n_equally_good`` points (``n_verified_good`` of them run), and
    ``linear_check`` what that says of the linear figure (``holds``, ``fails``, ``open``,
    ``unchecked``); ``ranges`` each parameter's span over the points and ``kinds`` which
    sides the target bounds (``two-sided``, ``lower-bound``, ``upper-bound``, ``free``).
    """

    exponents: dict[str, float]
    exponents_from: str
    combination: str
    combination_value: float
    relative_uncertainty: float
    set_spread: float
    n_equally_good: int
    ranges: dict[str, list[float]]
    linear_check: str
    n_verified_good: int
    kinds: dict[str, str]
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
    verified_good: int = 0,
    space: Any = None,
    predicted_by: str = "the surrogate",
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
    verified_good : int
        How many of ``equally_good`` (its last rows) the full solver ran.
    space : ParameterSpace, optional
        The declared ranges (each span's open sides); without it, every side counts as
        bounded.
    predicted_by : str
        What predicted the points that were not run (``log_f60``'s model).
    """
    log_chosen = np.log(np.asarray(chosen, dtype=float))
    exponents, scale = _exponents(log_f60, log_chosen, equally_good, solver_gradient)
    shown = [k for k in np.argsort(-np.abs(exponents)) if abs(exponents[k]) >= _SHOWN_EXPONENT]
    combination = " · ".join(f"{_LABELS.get(names[k], names[k])}^{exponents[k]:.2f}" for k in shown)
    value = float(np.exp(exponents @ log_chosen))
    spread, ranges = _equally_good_set(names, chosen, equally_good, exponents)
    # F60 within ±tolerance fixes the combination to ±tolerance / max|a| where F60 is
    # log-linear in it; the equally good set checks that over the ranges
    uncertainty = tolerance / scale
    verified_rows = np.atleast_2d(equally_good)[len(equally_good) - verified_good :]
    verified_spread = _equally_good_set(names, chosen, verified_rows, exponents)[0]
    check = _linear_check(len(equally_good), spread, verified_spread, uncertainty)
    counted = (
        f"{len(equally_good)} equally good points ({verified_good} verified, "
        f"{len(equally_good) - verified_good} predicted by {predicted_by})"
    )
    kinds = _kinds(names, equally_good, space)
    source = (
        (gradient_source or "full-solver runs at the result")
        if solver_gradient is not None
        else "the surrogate"
    )
    statement = (
        f"F60 = {target_n:.4g} N ± {100 * tolerance:g} % determines one combination near the "
        f"result, {combination}{_meaning(names, exponents)}, to ±{100 * uncertainty:.1f} % "
        f"(linear: exponents from {source}). "
        f"{_checked(check, counted, spread, verified_spread, uncertainty, predicted_by)} "
        f"The other directions are free: {_span(len(equally_good), ranges, kinds)}. "
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
        linear_check=check,
        n_verified_good=int(verified_good),
        kinds=kinds,
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


def _kinds(names: Sequence[str], equally_good: np.ndarray, space: Any) -> dict[str, str]:
    """What the target bounds of each parameter, from the set's span: a side the set
    reaches within ``OPEN_UNIT`` of the declared bound is open."""
    from ..calibration._determination import interval_kind_of  # identify loads first

    if not len(equally_good) or space is None:
        return dict.fromkeys(names, "two-sided")
    unit = space.to_unit(np.atleast_2d(equally_good))
    return {
        n: interval_kind_of(unit[:, k].min() > OPEN_UNIT, unit[:, k].max() < 1.0 - OPEN_UNIT)
        for k, n in enumerate(names)
    }


def _linear_check(n_good: int, spread: float, verified_spread: float, uncertainty: float) -> str:
    """``holds`` (the set scatters the combination within ``LINEAR_HOLDS`` × the linear
    ±), ``fails`` (the verified points alone scatter more), ``open`` (only the surrogate's
    predicted points do: they are not run) or ``unchecked`` (no other point)."""
    if n_good == 0:
        return "unchecked"
    if spread <= LINEAR_HOLDS * uncertainty:
        return "holds"
    return "fails" if verified_spread > LINEAR_HOLDS * uncertainty else "open"


def _checked(
    check: str, counted: str, spread: float, verified_spread: float, uncertainty: float, by: str
) -> str:
    """The linear figure against the equally good set's scatter of the combination."""
    if check == "unchecked":
        return "No other equally good point was found to check it against."
    linear = f"±{100 * uncertainty:.1f} %"
    if check == "holds":
        return f"Over the {counted} it scatters ±{100 * spread:.1f} %, as the linear figure says."
    if check == "fails":
        return (
            f"The verified points alone scatter it ±{100 * verified_spread:.0f} %: the linear "
            f"{linear} holds near the result only (across the ranges F60 depends on more than "
            "this combination)."
        )
    return (
        f"Over the {counted} it scatters ±{100 * spread:.0f} %, the predicted ones beyond the "
        f"linear {linear}; they are {by}'s, not run, so whether {linear} holds across the "
        "ranges is open (a full-solver run at the farthest would tell)."
    )


def _span(n_good: int, ranges: dict[str, list[float]], kinds: dict[str, str]) -> str:
    if n_good == 0:
        return "no other equally good point was found"
    words = []
    for n, (lo, hi) in ranges.items():
        kind = kinds.get(n, "two-sided")
        low = f"{lo:.3g}" + (" (at its lower bound)" if kind in ("upper-bound", "free") else "")
        high = f"{hi:.3g}" + (" (at its upper bound)" if kind in ("lower-bound", "free") else "")
        words.append(f"{_LABELS.get(n, n)} {low}–{high}")
    return f"the equally good points span {', '.join(words)}"


def _preferences(order: Sequence[str]) -> str:
    return ", then ".join(f"lower {_LABELS.get(n, n)}" for n in order) or "none"
