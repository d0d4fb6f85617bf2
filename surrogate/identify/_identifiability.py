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
statement says the linear figure holds near the result only. Only points besides the
result check it, and only verified ones make the check a finding. Each parameter's span
over the set says which declared bounds it reaches (within ``BOUND_UNIT``), and whether
a verified point or only a predicted one does. The set is what the search found, so a
span is at least that wide — never a confidence interval; the predicted points are the
surrogate's, not run. The preferences pick one point from it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..study._space import ParameterSpace

__all__ = ["Identifiability", "assess_identifiability"]

_SHOWN_EXPONENT = 0.05
LINEAR_HOLDS = 1.5  # the set's scatter of the combination within this × the linear ±: it holds
BOUND_UNIT = 0.02  # a span this near a bound (share of its range, log where declared) reaches it
_LABELS = {"ecoat_gpa": "Ecoat", "scoat_gpa": "Scoat", "tcoat_mm": "Tcoat"}


@dataclass(frozen=True)
class Identifiability:
    """The identifiability statement of a result (fields are its JSON keys).

    ``relative_uncertainty`` is the linear ± of the combination; ``set_spread`` its
    scatter over the ``n_equally_good`` points (``n_verified_good`` of them run, the
    result among them), and ``linear_check`` what that says of the linear figure:
    ``holds`` (verified points besides the result take part), ``fails`` (the verified
    points alone scatter it more), ``open`` (the verdict rests on predicted points only)
    or ``unchecked`` (no point besides the result). ``ranges`` is each parameter's span
    over the points and ``bounds_reached`` which declared bound it reaches, by side
    (``low``, ``high``): ``verified``, ``predicted`` (only predicted points do) or None.
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
    bounds_reached: dict[str, dict[str, str | None]]
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
    space: ParameterSpace | None = None,
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
        The declared ranges (the bounds a span reaches); without it, none is said to.
    predicted_by : str
        What predicted the points that were not run (``log_f60``'s model).
    """
    log_chosen = np.log(np.asarray(chosen, dtype=float))
    exponents, scale = _exponents(log_f60, log_chosen, equally_good, solver_gradient)
    shown = [k for k in np.argsort(-np.abs(exponents)) if abs(exponents[k]) >= _SHOWN_EXPONENT]
    combination = " · ".join(f"{_LABELS.get(names[k], names[k])}^{exponents[k]:.2f}" for k in shown)
    value = float(np.exp(exponents @ log_chosen))
    good = np.atleast_2d(np.asarray(equally_good, dtype=float)).reshape(-1, len(names))
    if not 0 <= verified_good <= len(good):
        raise ValueError(f"verified_good = {verified_good} must lie in 0–{len(good)}")
    verified = np.arange(len(good)) >= len(good) - verified_good  # the last rows
    spread, ranges = _equally_good_set(names, chosen, good, exponents)
    # F60 within ±tolerance fixes the combination to ±tolerance / max|a| where F60 is
    # log-linear in it; the equally good set checks that over the ranges
    uncertainty = tolerance / scale
    verified_spread = _equally_good_set(names, chosen, good[verified], exponents)[0]
    others = ~np.all(good == np.asarray(chosen, dtype=float), axis=1)
    check = _linear_check(
        int(others.sum()), int((others & verified).sum()), spread, verified_spread, uncertainty
    )
    counted = (
        f"{_points(len(good))} ({int(verified.sum())} verified, "
        f"{int((~verified).sum())} predicted by {predicted_by})"
    )
    reached = _bounds_reached(names, good, verified, space)
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
        f"The other directions are free: {_span(len(good), ranges, reached)}. "
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
        bounds_reached=reached,
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


def _points(n: int) -> str:
    return f"{n} equally good point{'' if n == 1 else 's'}"


def _bounds_reached(
    names: Sequence[str], good: np.ndarray, verified: np.ndarray, space: ParameterSpace | None
) -> dict[str, dict[str, str | None]]:
    """Which declared bound each parameter's span reaches (within ``BOUND_UNIT``), by
    side: ``verified`` (a verified point does), ``predicted`` (only predicted ones) or
    None."""
    if not len(good) or space is None:
        return {n: {"low": None, "high": None} for n in names}
    unit = space.to_unit(good)
    sides = {"low": unit <= BOUND_UNIT, "high": unit >= 1.0 - BOUND_UNIT}
    return {
        n: {
            side: "verified"
            if np.any(near[:, k] & verified)
            else "predicted"
            if np.any(near[:, k])
            else None
            for side, near in sides.items()
        }
        for k, n in enumerate(names)
    }


def _linear_check(
    others: int, verified_others: int, spread: float, verified_spread: float, uncertainty: float
) -> str:
    """``holds``, ``fails``, ``open`` or ``unchecked`` (:class:`Identifiability`): the
    scatter of the combination over the points (``spread``; over the verified ones,
    ``verified_spread``) against ``LINEAR_HOLDS`` × the linear ± (``uncertainty``), with
    ``others`` points besides the result (``verified_others`` of them verified)."""
    limit = LINEAR_HOLDS * uncertainty
    if others == 0:
        return "unchecked"
    if verified_spread > limit:
        return "fails"
    return "holds" if spread <= limit and verified_others > 0 else "open"


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
            f"The verified points alone scatter it ±{100 * verified_spread:.1f} %: the linear "
            f"{linear} holds near the result only (across the ranges F60 depends on more than "
            "this combination)."
        )
    if spread <= LINEAR_HOLDS * uncertainty:
        return (
            f"Over the {counted} it scatters ±{100 * spread:.1f} %, as the linear figure says, "
            f"but only {by}'s predicted points, not run, bear that out (a full-solver run at "
            "the farthest would tell)."
        )
    return (
        f"Over the {counted} it scatters ±{100 * spread:.1f} %, the predicted ones beyond the "
        f"linear {linear}; they are {by}'s, not run, so whether {linear} holds across the "
        "ranges is open (a full-solver run at the farthest would tell)."
    )


def _span(n_good: int, ranges: dict[str, list[float]], reached: dict[str, dict]) -> str:
    if n_good == 0:
        return "no other equally good point was found"
    said = {"verified": "at its {} bound", "predicted": "at its {} bound: predicted, not run"}
    words = []
    for n, (lo, hi) in ranges.items():
        low, high = (reached.get(n) or {}).get("low"), (reached.get(n) or {}).get("high")
        low_text = f"{lo:.3g}" + (f" ({said[low].format('lower')})" if low else "")
        high_text = f"{hi:.3g}" + (f" ({said[high].format('upper')})" if high else "")
        words.append(f"{_LABELS.get(n, n)} {low_text}–{high_text}")
    return f"the equally good points span {', '.join(words)}"


def _preferences(order: Sequence[str]) -> str:
    return ", then ".join(f"lower {_LABELS.get(n, n)}" for n in order) or "none"
