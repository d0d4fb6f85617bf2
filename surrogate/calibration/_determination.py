"""What the measured curves determine: the linearised covariance at a calibrated point.

Pure numerics: arrays in, a frozen record out.

Notations
---------
``z`` : (p,)
    Parameters in their declared scale: ``log θ`` where the parameter is
    log-scaled, ``θ`` otherwise; ``span`` its range in that scale, so that
    ``u = (z − z_low) / span`` are the unit coordinates of the fit.
``J_u`` : (n, p)
    ``∂r/∂u`` at the calibrated point (finite differences of the full solver);
    ``J_z = J_u / span``.
``s²``
    ``RSS / (n − p_free)``: the residual variance (the noise, when the model fits).
``C = s² (J_zᵀ J_z)⁻¹`` over the parameters not held at a bound, by its
    eigen-decomposition; a direction whose eigenvalue is below ``NULL_EIGENVALUE``
    of the largest is not determined at all (infinite variance).

A combination ``f(θ)`` (the bending stiffness ``D``, the plastic moment ``Mp``)
gets ``var log f = gᵀ C g`` with ``g = ∂ log f / ∂z`` (central differences) over the
determined directions, its 95 % interval ``f · exp(± (t₀.₉₇₅ · sd + m))`` with ``m``
how far ``log f`` moves along the undetermined directions within the ranges (first
order; ``_Covariance.spread``). A parameter whose 95 % interval spans at least
``FREE_SHARE`` of its range is *free*: that wide, the linearisation is not trusted
(the valley of equally good thin-coat solutions is curved), so its interval is the
whole range.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

__all__ = [
    "Determination",
    "checked",
    "determination_threshold",
    "determine",
    "interval_kind_of",
    "linear_entries",
]

LEVEL = 0.95
FREE_SHARE = 0.25  # a 95 % interval this wide a share of the range: the linearisation is not
# trusted and the parameter is free within its range (measured: a thin coat's Ecoat–Tcoat
# valley gives 40–50 %, determined parameters < 1 %)
NULL_EIGENVALUE = 1e-12  # relative to the largest: numerically singular
_LABELS = {"ecoat_gpa": "Ecoat", "scoat_gpa": "Scoat", "tcoat_mm": "Tcoat"}
# a combination loading its free parameters by no more than this share of its largest load
# is held by the bounds (D = f(Ecoat, Tcoat) with both at a bound: not "±0 %")
HELD_LOAD = 1e-9


def at_bound_text(name: str, side: int, bound: float, verb: str = "held at") -> str:
    """The words for a parameter at a bound of its range (``side`` −1 lower, +1 upper;
    ``bound`` the range's end), e.g. "Ecoat held at its lower bound 0.5"."""
    side_name = "lower" if side < 0 else "upper"
    return f"{_LABELS.get(name, name)} {verb} its {side_name} bound {bound:.4g}"


@dataclass(frozen=True)
class Determination:
    """What the curves determine at a calibrated point (fields are its JSON keys).

    ``combinations``: for each named combination (``bending_stiffness_nmm``,
    ``plastic_moment_n``) its ``value``, 95 % ``low``/``high`` and
    ``relative_half_width`` (``±`` fraction); ``intervals``: the 95 % interval of
    each parameter, clipped to its range (``None`` where it is held at a bound);
    ``free``: parameters whose linearised interval spans ≥ ``FREE_SHARE`` of the
    range (their interval is then the whole range); a
    combination along a direction the curves do not determine at all, or of
    parameters all held at a bound (``held_by_bounds``: the ranges hold it), has
    ``None`` bounds;
    ``held_at_bound``: parameters the fit
    holds at a bound of their range; ``directions``: eigen-directions of the
    covariance in the declared scale, best determined first, each with its 95 %
    ``half_width`` (in ``z``; ``None``: not determined) and ``weights`` (largest
    ±1); ``sigma_n``: ``s``.
    """

    sigma_n: float
    dof: int
    combinations: dict[str, dict[str, Any]]
    intervals: dict[str, Any]  # linear: [low, high] or None; checked: an entry like a combination's
    free: list[str]
    held_at_bound: list[str]
    directions: list[dict[str, Any]]
    statement: str
    profile_solver_calls: int | None = None
    verification_solver_calls: int | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def determine(
    names: Sequence[str],
    low: np.ndarray,
    high: np.ndarray,
    log: np.ndarray,
    theta: np.ndarray,
    jacobian_unit: np.ndarray,
    residual: np.ndarray,
    at_bound: np.ndarray,
    *,
    combinations: Mapping[str, tuple[str, Callable[[Mapping[str, float]], float]]] = {},
) -> Determination:
    """The linearised 95 % statement of what the curves determine.

    Parameters
    ----------
    names : sequence of str, (p,)
        Parameter names.
    low, high : ndarray, (p,)
        Bounds in the declared units.
    log : ndarray of bool, (p,)
        Log-scaled parameters.
    theta : ndarray, (p,)
        The calibrated point, declared units.
    jacobian_unit : ndarray, (n, p)
        ``∂r/∂u`` at ``theta``.
    residual : ndarray, (n,)
        Measured minus model at ``theta`` [N].
    at_bound : ndarray of int, (p,)
        −1/+1 where a parameter is at its lower/upper bound, else 0.
    combinations : mapping
        Name → (label, function of the parameter mapping), e.g.
        ``"bending_stiffness_nmm": ("D ∝ Ecoat·Tcoat", D)``.
    """
    log = np.asarray(log, bool)
    z_low, z = _to_z(low, log), _to_z(theta, log)
    span = _to_z(high, log) - z_low
    free_index = np.flatnonzero(np.asarray(at_bound) == 0)
    dof = max(residual.size - free_index.size, 1)
    covariance = _Covariance.of(jacobian_unit[:, free_index] / span[free_index], residual, dof)
    t = float(stats.t.ppf(0.5 + LEVEL / 2, dof))
    intervals, free, held = _intervals(names, z, z_low, span, log, free_index, covariance, t)
    found = {
        key: _combination(function, names, z, log, free_index, covariance, span, t)
        for key, (_, function) in combinations.items()
    }
    labels = {key: label for key, (label, _) in combinations.items()}
    ends = np.where(np.asarray(at_bound) < 0, low, high)  # the bound each held one is at
    statement = _statement(names, theta, intervals, found, labels, free, held, at_bound, ends)
    return Determination(
        sigma_n=covariance.sigma,
        dof=dof,
        combinations=found,
        intervals=intervals,
        free=free,
        held_at_bound=held,
        directions=_directions(names, free_index, covariance, t),
        statement=statement,
    )


def determination_threshold(rss: float, dof: int) -> float:
    """The 95 % threshold of a profile: how far above ``rss`` a re-fit's RSS may lie,
    ``t²₀.₉₇₅(dof) · rss/dof`` (the F-test of one parameter, :mod:`._profile`)."""
    t = float(stats.t.ppf(0.5 + LEVEL / 2, max(dof, 1)))
    return t * t * rss / max(dof, 1)


def _to_z(values: np.ndarray, log: np.ndarray) -> np.ndarray:
    """Values in the declared scale ``z`` (``log θ`` where log-scaled)."""
    return np.where(log, np.log(np.where(log, values, 1.0)), values)


@dataclass(frozen=True)
class _Covariance:
    """``C = s² (J_zᵀ J_z)⁻¹`` over the free parameters, by its eigen-decomposition."""

    sigma: float
    eigenvalues: np.ndarray
    vectors: np.ndarray
    determined: np.ndarray  # eigen-directions the curves determine at all

    @classmethod
    def of(cls, jac_z: np.ndarray, residual: np.ndarray, dof: int) -> _Covariance:
        sigma = math.sqrt(float(residual @ residual) / dof)
        eigenvalues, vectors = np.linalg.eigh(jac_z.T @ jac_z)
        largest = max(float(eigenvalues.max(initial=0.0)), 1e-300)
        return cls(sigma, eigenvalues, vectors, eigenvalues > NULL_EIGENVALUE * largest)

    def spread(self, gradient_free: np.ndarray, span_free: np.ndarray) -> tuple[float, float]:
        """Standard deviation of ``gradient · z`` over the determined directions, and how
        far ``gradient · z`` moves along the undetermined ones within the ranges (each
        direction's longest chord in the box of ``span_free``, first order).

        A combination the curves determine (D on a thin coat's Ecoat–Tcoat valley) still
        loads on the valley by what the linearisation and the finite differences leave
        (1e-9 of its largest load or more, machine-dependent): counted as the move it
        allows within the ranges, not as an infinite variance — which made D
        "undetermined" on one BLAS and determined on another."""
        loads = self.vectors.T @ gradient_free
        move = 0.0
        for k in np.flatnonzero(~self.determined):
            direction = np.abs(self.vectors[:, k])
            along = direction > 0
            move += abs(float(loads[k])) * float(np.min(span_free[along] / direction[along]))
        return self._determined_sd(loads), move

    def sd(self, gradient_free: np.ndarray) -> float:
        """Standard deviation of ``gradient · z`` (inf along an undetermined direction)."""
        loads = self.vectors.T @ gradient_free
        if np.any(np.abs(loads[~self.determined]) > 1e-9 * max(np.abs(loads).max(), 1e-300)):
            return math.inf
        return self._determined_sd(loads)

    def _determined_sd(self, loads: np.ndarray) -> float:
        """``σ · √(Σ load² / λ)`` over the determined eigen-directions."""
        determined = self.determined
        return self.sigma * math.sqrt(
            float(np.sum(loads[determined] ** 2 / self.eigenvalues[determined]))
        )


def _intervals(
    names: Sequence[str],
    z: np.ndarray,
    z_low: np.ndarray,
    span: np.ndarray,
    log: np.ndarray,
    free_index: np.ndarray,
    covariance: _Covariance,
    t: float,
) -> tuple[dict[str, list[float] | None], list[str], list[str]]:
    """The 95 % interval of each parameter (None where held at a bound), the free
    parameters and those held at a bound."""
    intervals: dict[str, list[float] | None] = {}
    free, held = [], []
    position = {int(k): i for i, k in enumerate(free_index)}
    for k, name in enumerate(names):
        if k not in position:
            held.append(name)
            intervals[name] = None
            continue
        half = t * covariance.sd(np.eye(free_index.size)[position[k]])
        if 2 * half >= FREE_SHARE * span[k]:
            free.append(name)
            half = math.inf
        # clipped to the declared range: what the study already knew
        edges = np.clip(z[k] + np.array([-half, half]), z_low[k], z_low[k] + span[k])
        intervals[name] = [float(v) for v in (np.exp(edges) if log[k] else edges)]
    return intervals, free, held


def _directions(
    names: Sequence[str], free_index: np.ndarray, covariance: _Covariance, t: float
) -> list[dict[str, Any]]:
    """Eigen-directions of the covariance, best determined first: 95 % half-width in ``z``
    (None: not determined) and weights (largest ±1)."""
    directions = []
    for index in np.argsort(-covariance.eigenvalues):
        vector = covariance.vectors[:, index]
        weights = vector / np.max(np.abs(vector))
        width = (
            t * covariance.sigma / math.sqrt(covariance.eigenvalues[index])
            if covariance.determined[index]
            else None
        )
        directions.append(
            {
                "half_width": width,
                "weights": {
                    names[int(k)]: float(w) for k, w in zip(free_index, weights, strict=True)
                },
            }
        )
    return directions


def _combination(
    function: Callable[[Mapping[str, float]], float],
    names: Sequence[str],
    z: np.ndarray,
    log: np.ndarray,
    free_index: np.ndarray,
    covariance: _Covariance,
    span: np.ndarray,
    t: float,
) -> dict[str, Any]:
    def log_value(zz: np.ndarray) -> float:
        theta = zz.copy()
        theta[log] = np.exp(zz[log])
        return math.log(function(dict(zip(names, map(float, theta), strict=True))))

    step = 1e-6
    every = np.array(
        [(log_value(z + step * e) - log_value(z - step * e)) / (2 * step) for e in np.eye(z.size)]
    )
    gradient = every[free_index]
    value = math.exp(log_value(z))
    none = {"value": value, "low": None, "high": None, "relative_half_width": None}
    if not np.any(np.abs(gradient) > HELD_LOAD * np.abs(every).max(initial=0.0)):
        # every parameter it depends on is held at a bound: the range holds it, not the curves
        return {**none, "held_by_bounds": True}
    sd, move = covariance.spread(gradient, span[free_index])
    half = t * sd + move  # the valley's move within the ranges: a share of it, not a variance
    if not half < 700.0:  # inf, or exp would overflow: a direction the curves do not determine
        return {**none, "held_by_bounds": False}
    return {
        "value": value,
        "low": value * math.exp(-half),
        "high": value * math.exp(half),
        "relative_half_width": math.expm1(half),
        "held_by_bounds": False,
    }


def parameter_interval_text(name: str, determination: Mapping[str, Any]) -> str:
    """A parameter's 95 % interval as the note, the CLI and the report show it."""
    return interval_text(determination["intervals"][name])


def interval_text(entry: Mapping[str, Any]) -> str:
    """A 95 % interval (a combination's or a parameter's checked entry) as the note, the
    CLI and the report show it: both ends, one bound, or free; and how it was found."""
    low, high, kind = entry["low"], entry["high"], entry["kind"]
    how = {"profile": "profile", "linear": "linear, checked", "unchecked": "linear, not checked"}
    tail = f" ({how[entry['method']]})"
    if kind == "two-sided":
        return f"{low:.4g} – {high:.4g}{tail}"
    reason = f"; {entry['reason']}" if entry.get("reason") else ""
    if kind == "lower-bound":
        return f"≥ {low:.4g}, a lower bound only{reason}{tail}"
    if kind == "upper-bound":
        return f"≤ {high:.4g}, an upper bound only{reason}{tail}"
    if entry.get("held_by_bounds"):
        return f"held by the ranges (its parameters at bounds){tail}"
    return f"free within its range{reason}{tail}"


def linear_entries(
    linear: Determination,
    names: Sequence[str],
    theta: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
) -> dict[str, dict[str, Any]]:
    """The linear intervals as :func:`checked`'s entries, ``method`` ``unchecked``: an end
    clipped at its range's end is open, a free or held parameter has none."""
    entries: dict[str, dict[str, Any]] = {}
    for key, c in linear.combinations.items():
        entries[key] = {
            "value": c["value"],
            "low": c["low"],
            "high": c["high"],
            "kind": interval_kind_of(c["low"] is not None, c["high"] is not None),
            "method": "unchecked",
        }
    for k, name in enumerate(names):
        interval = linear.intervals.get(name)
        ends = [None, None] if interval is None or name in linear.free else list(interval)
        if ends[0] is not None and ends[0] <= low[k] * (1 + 1e-9):
            ends[0] = None
        if ends[1] is not None and ends[1] >= high[k] * (1 - 1e-9):
            ends[1] = None
        entries[name] = {
            "value": float(theta[k]),
            "low": ends[0],
            "high": ends[1],
            "kind": interval_kind_of(ends[0] is not None, ends[1] is not None),
            "method": "unchecked",
        }
    return entries


def interval_kind_of(has_low: bool, has_high: bool) -> str:
    """What an interval with these ends bounds: ``two-sided``, ``lower-bound`` (only its
    low end is the data's), ``upper-bound`` or ``free``."""
    if has_low and has_high:
        return "two-sided"
    if has_low:
        return "lower-bound"
    return "upper-bound" if has_high else "free"


def _statement(
    names: Sequence[str],
    theta: np.ndarray,
    intervals: Mapping[str, list[float] | None],
    combinations: Mapping[str, dict[str, float | None]],
    labels: Mapping[str, str],
    free: Sequence[str],
    held: Sequence[str],
    at_bound: np.ndarray,
    ends: np.ndarray,
) -> str:
    parts = [
        f"{labels[key]} to ±{100 * c['relative_half_width']:.2g} %"
        for key, c in combinations.items()
        if c["relative_half_width"] is not None
    ]
    text = "the curves determine " + (" and ".join(parts) if parts else "no named combination")
    text += f" ({100 * LEVEL:g} %)"
    if free:
        label = ", ".join(_LABELS.get(n, n) for n in free)
        text += f"; {label} apart {'are' if len(free) > 1 else 'is'} free within the ranges"
    for k, name in enumerate(names):
        if name in held:
            text += "; " + at_bound_text(name, int(at_bound[k]), float(ends[k]))
    effect_parts = [
        f"{name} {theta[k]:.3g} [{intervals[name][0]:.3g}, {intervals[name][1]:.3g}]"  # type: ignore[index]
        for k, name in enumerate(names)
        if "." in name and intervals.get(name) is not None and name not in free
    ]
    if effect_parts:
        text += "; " + ", ".join(effect_parts)
    return text


# -- the record with every interval checked (profiles, :mod:`._profile`) ------------------------
def checked(
    linear: Determination,
    names: Sequence[str],
    theta: np.ndarray,
    entries: Mapping[str, Mapping[str, Any]],
    labels: Mapping[str, str],
    *,
    solver_calls: int,
) -> Determination:
    """The determination with every interval a checked claim: ``entries`` maps each
    combination and parameter to ``{value, low, high, kind, method}`` (``low``/``high``
    None on an open side; optionally ``reason``: why a side is open, e.g. "the curves
    show no plateau before 90°"), from the profiles; ``labels`` the combinations' labels.
    ``directions`` and ``sigma_n`` stay the linearisation's; ``free`` lists the parameters
    of kind ``free``; ``profile_solver_calls`` the runs the profiles cost."""
    combinations = {
        key: _with_width(dict(entries[key]), linear.combinations[key].get("held_by_bounds"))
        for key in linear.combinations
    }
    intervals = {name: dict(entries[name]) for name in names}
    free = [name for name in names if intervals[name]["kind"] == "free"]
    statement = _checked_statement(names, theta, combinations, intervals, labels, linear)
    return Determination(
        sigma_n=linear.sigma_n,
        dof=linear.dof,
        combinations=combinations,
        intervals=intervals,
        free=free,
        held_at_bound=linear.held_at_bound,
        directions=linear.directions,
        statement=statement,
        profile_solver_calls=solver_calls,
    )


def _with_width(entry: dict[str, Any], held_by_bounds: Any) -> dict[str, Any]:
    """A combination's entry with ``relative_half_width`` (the larger side's, two-sided
    only) and ``held_by_bounds`` (False where the profile bounds it from either side)."""
    value, low, high = entry["value"], entry["low"], entry["high"]
    width = None
    if low is not None and high is not None:
        width = max(value / low - 1.0, high / value - 1.0)
    bounded = low is not None or high is not None
    return {
        **entry,
        "relative_half_width": width,
        "held_by_bounds": bool(held_by_bounds) and not bounded,
    }


def _percent(value: float) -> str:
    return f"{100 * value:.2g} %"


def _combination_phrase(label: str, entry: Mapping[str, Any]) -> str:
    """How the statement says what the curves determine of a combination."""
    value, low, high, kind = entry["value"], entry["low"], entry["high"], entry["kind"]
    short = label.split(" ", 1)[0]  # "D", "Mp"
    reason = f" ({entry['reason']})" if entry.get("reason") else ""
    if kind == "two-sided":
        below, above = 1.0 - low / value, high / value - 1.0
        if max(below, above) <= 1.25 * min(below, above):
            return f"{label} to ±{_percent(max(below, above))}"
        return f"{label} to −{_percent(below)}/+{_percent(above)}"
    if kind == "lower-bound":
        return f"{short} ≥ {low:.4g} only{reason}"
    if kind == "upper-bound":
        return f"{short} ≤ {high:.4g} only{reason}"
    return f"no bound on {short} within the ranges{reason}"


def _parameter_phrase(name: str, entry: Mapping[str, Any]) -> str:
    label = _LABELS.get(name, name)
    low, high, kind = entry["low"], entry["high"], entry["kind"]
    if kind == "two-sided":
        return f"{label} {entry['value']:.3g} [{low:.3g}, {high:.3g}]"
    if kind == "lower-bound":
        return f"{label} ≥ {low:.3g}"
    return f"{label} ≤ {high:.3g}"


def _checked_statement(
    names: Sequence[str],
    theta: np.ndarray,
    combinations: Mapping[str, Mapping[str, Any]],
    intervals: Mapping[str, Mapping[str, Any]],
    labels: Mapping[str, str],
    linear: Determination,
) -> str:
    """The one sentence of what the curves determine (every interval checked)."""
    parts = [_combination_phrase(labels[key], c) for key, c in combinations.items()]
    method = (
        "profile"
        if any(e["method"] == "profile" for e in (*combinations.values(), *intervals.values()))
        else "linear, checked"
    )
    text = "the curves determine " + (" and ".join(parts) if parts else "no named combination")
    text += f" ({100 * LEVEL:g} %, {method})"
    free = [n for n in names if intervals[n]["kind"] == "free"]
    if free:
        label = ", ".join(_LABELS.get(n, n) for n in free)
        text += f"; {label} apart {'are' if len(free) > 1 else 'is'} free within the ranges"
    bounded = [
        _parameter_phrase(n, intervals[n])
        for n in names
        if intervals[n]["kind"] != "free" and ("." in n or intervals[n]["kind"] != "two-sided")
    ]
    coating_two_sided = [
        _parameter_phrase(n, intervals[n])
        for n in names
        if "." not in n and intervals[n]["kind"] == "two-sided"
    ]
    if coating_two_sided + bounded:
        text += "; " + ", ".join(coating_two_sided + bounded)
    if any(c["method"] == "unchecked" for c in (*combinations.values(), *intervals.values())):
        text += (
            "; some ends were not checked (the profiles' budget was spent, or a re-fit could "
            "not reach them or follow a trade of parameters): linear there, open where the "
            "linear interval has no end or the re-fits found the misfit flat towards it"
        )
    for name in linear.held_at_bound:
        k = list(names).index(name)
        text += "; " + at_bound_text(name, _held_side(name, intervals[name], theta[k]), theta[k])
    return text


def _held_side(name: str, entry: Mapping[str, Any], value: float) -> int:
    """The side of its range a held parameter is at: −1 lower (its low side open); where
    both sides are open (the other one a bound holds: ``_profile``'s ``_walled``), the side
    whose re-fit is the optimum itself (a side at the parameter's own range end is open at
    once, its point the optimum's)."""
    if (entry["low"] is None) == (entry["high"] is None):
        points = entry.get("points") or {}
        for key, side in (("high", 1), ("low", -1)):
            point = points.get(key)
            found = None if point is None else point["params"].get(name)
            if found is not None and math.isclose(found, value, rel_tol=1e-9):
                return side
    return -1 if entry["low"] is None else 1
