"""Other basins: where a calibration looks before it reports a misfit the noise does not
explain, and the local optima it found.

A local optimum whose misfit is systematic is either the model's (an effect is
missing) or the search's (another basin fits better). Seen: anisotropic data whose weft
coat yields, calibrated with ``anisotropy`` (study seed 2): a verified local optimum at
21 × the noise with the weft factor of the yield stress ``a_s`` 1.37, where no weft test
yields and ``a_s`` does not matter at all; the truth, ``a_s`` 0.7, fits to the noise.
The diagnosis then named ``friction``, whose local refit merely carried the model out of
that basin. So before such a misfit is reported, the local phase restarts from diverse
points (:func:`basin_starts`) — along the least determined direction, each effect
parameter across its range, the surrogate's best points away from every optimum found —
each first screened by a short ``least_squares`` run (no first-order test), and fitted to
a verified local optimum only where the screen ends better than the best one.

The search spends at most ``BASIN_SHARE`` of the calibration's budget; it ends early
where a fit comes within the noise. :class:`BasinSearch` is its record (the ``basins``
key of ``calibrate --json``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ._local import LocalFit

__all__ = [
    "BASIN_SHARE",
    "SAME_OPTIMUM_UNIT",
    "SCREEN_EVALUATIONS",
    "UNAFFORDABLE",
    "BasinSearch",
    "Start",
    "distinct_optima",
    "effect_starts",
    "far_from",
    "optima_record",
    "spread_rows",
]

BASIN_SHARE = 0.5  # the share of the calibration's budget the search may spend, at most
# the reason of a search the budget left no run for, and the message's words for it
UNAFFORDABLE = "the budget left no run to search other basins"
# an effect parameter's starts: these points of its range (unit coordinates) and its off value
EFFECT_GRID = (0.05, 0.25, 0.5, 0.75, 0.95)
NEAR_UNIT = 0.1  # a start within this of a known optimum in every coordinate: not a new one
SAME_OPTIMUM_UNIT = 0.02  # two optima this close in every coordinate are one
SCREEN_EVALUATIONS = 12  # residual evaluations of a start's short least_squares run


@dataclass(frozen=True)
class Start:
    """A point the local phase restarts from, and what chose it (for the log)."""

    theta: np.ndarray
    why: str


@dataclass(frozen=True)
class BasinSearch:
    """Whether other basins were searched, and the local optima found (``basins`` key).

    ``searched`` is True where the search ran (the best verified local optimum's misfit
    was systematic); ``reason`` says why it ran or did not. ``starts`` counts the points
    screened, ``solver_calls`` the runs the search spent (within ``BASIN_SHARE`` of the
    budget). ``optima``: the distinct local optima the calibration verified (its
    first-order test held), best first, each ``{rmse_n, params, where}`` (``where``: the
    parameters in which it differs most from the best, "" for the best itself); the
    first is the reported point where the calibration converged.
    """

    searched: bool
    reason: str
    starts: int = 0
    solver_calls: int = 0
    optima: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    def sentence(self, noise: float) -> str:
        """What the search found, for the calibration's message ("" where it did not run,
        but for a systematic misfit whose search the budget left no run for)."""
        if not self.searched:
            if self.reason != UNAFFORDABLE:
                return ""
            return (
                f"; the first local optimum's misfit was systematic, but {UNAFFORDABLE}: "
                "another may fit better (raise --budget)"
            )
        searched = (
            "; the first local optimum's misfit was systematic, so other basins were searched "
            f"({self.starts} start(s), {self.solver_calls} solver runs)"
        )
        if len(self.optima) < 2:
            return f"{searched}: no other local optimum found"
        nxt = self.optima[1]
        return (
            f"{searched}: best of {len(self.optima)} local optima, the next is "
            f"{nxt['rmse_n'] / noise:.3g} × noise" + (f" at {nxt['where']}" if nxt["where"] else "")
        )


def effect_starts(space: Any, theta: np.ndarray, offs: dict[str, float]) -> list[Start]:
    """Each effect parameter (``effect.param``) moved across its range — ``EFFECT_GRID``
    and its off value (``offs``) — the others kept at ``theta``; none within
    ``NEAR_UNIT`` of its value at ``theta``."""
    unit = space.to_unit(theta[None, :])[0]
    starts = []
    for k, spec in enumerate(space):
        if "." not in spec.name:
            continue
        targets = list(EFFECT_GRID)
        off = offs.get(spec.name)
        if off is not None and np.isfinite(off):
            targets.insert(0, float(spec.to_unit(min(max(off, spec.low), spec.high))))
        for target in targets:
            if abs(target - unit[k]) < NEAR_UNIT:
                continue
            moved = unit.copy()
            moved[k] = target
            point = space.clip(space.from_unit(moved[None, :])[0])
            starts.append(Start(point, f"{spec.name} at {point[k]:.3g}"))
    return starts


def far_from(
    unit: np.ndarray, known: Sequence[np.ndarray] | np.ndarray, within: float = NEAR_UNIT
) -> bool:
    """Whether a unit point lies farther than ``within`` (in some coordinate) from every
    known one (``known``: a sequence of points or an (m, p) array)."""
    if len(known) == 0:
        return True
    others = np.asarray(known, dtype=float).reshape(len(known), -1)
    return bool(np.all(np.max(np.abs(others - unit), axis=1) > within))


def spread_rows(units: np.ndarray, first: Sequence[np.ndarray], within: float) -> np.ndarray:
    """The rows of ``units`` (n, p) to keep, a bool mask (n,): those at a point of
    ``first`` (kept whatever their spacing: the verified points and optima) and, in their
    order, those farther than ``within`` (:func:`far_from`) from every kept point; a kept
    point's rows at other condition groups (the same point) are kept with it."""
    kept = np.empty((len(first) + len(units), units.shape[1]))
    count = len(first)
    kept[:count] = np.asarray(first, dtype=float).reshape(count, units.shape[1])
    keys = {point.tobytes() for point in kept[:count]}
    keep = np.zeros(len(units), dtype=bool)
    for row, unit in enumerate(units):
        known = unit.tobytes() in keys
        if known or far_from(unit, kept[:count], within):
            keep[row] = True
            if not known:
                kept[count], count = unit, count + 1
                keys.add(unit.tobytes())
    return keep


def distinct_optima(fits: Sequence[LocalFit]) -> list[LocalFit]:
    """The converged fits, best first, one per optimum (within ``SAME_OPTIMUM_UNIT``)."""
    kept: list[LocalFit] = []
    for fit in sorted((f for f in fits if f.converged), key=lambda f: f.rmse):
        if far_from(fit.unit, [k.unit for k in kept], SAME_OPTIMUM_UNIT):
            kept.append(fit)
    return kept


def where_they_differ(space: Any, best: LocalFit, other: LocalFit, count: int = 2) -> str:
    """The ``count`` parameters in which ``other`` differs most from ``best`` (a share of
    each range, unit coordinates), with ``other``'s values, e.g. "anisotropy.a_s 1.37"."""
    moved = np.abs(other.unit - best.unit)
    order = [k for k in np.argsort(-moved, kind="stable") if moved[k] > SAME_OPTIMUM_UNIT]
    return ", ".join(f"{space.names[k]} {other.theta[k]:.3g}" for k in order[:count])


def optima_record(space: Any, fits: Sequence[LocalFit]) -> list[dict[str, Any]]:
    """The ``optima`` of :class:`BasinSearch`: :func:`distinct_optima` of ``fits``."""
    optima = distinct_optima(fits)
    return [
        {
            "rmse_n": fit.rmse,
            "params": dict(zip(space.names, map(float, fit.theta), strict=True)),
            "where": "" if k == 0 else where_they_differ(space, optima[0], fit),
        }
        for k, fit in enumerate(optima)
    ]
