"""Profile intervals: what the curves determine, by constrained re-fits with the solver.

The linearised (delta-method) interval of :mod:`._determination` is a shortcut: where
the curves bound a quantity from one side only — a coat whose curves never reach their
plateau before 90° fits as well with any larger plastic moment — or where the misfit
rises along a curved valley, it can exclude the truth (seen: "Mp to ±13 %" with the
truth 25.7 % above; "Tcoat ±0.07 %" with the truth 17 % below). The profile re-fits the
model with the quantity held, and keeps the values whose re-fit stays under the
threshold (Raue et al. 2009; lmfit's ``conf_interval``; Bates & Watts 1988, §6.1).

Notations
---------
``x`` : (p,)
    The fit coordinates of the local phase (:class:`~._local.FitCoordinates`: log D,
    log Mp and Tcoat for the coating, every other parameter its unit coordinate); the
    box ``[0, 1]^p`` is the declared one.
``q(x)``
    The profiled quantity in its declared scale: ``log`` of D, Mp and a log-scaled
    parameter, the value of a linear one; ``q*`` at the optimum ``x*``.
``RSS*``, ``s² = RSS*/dof``, ``Δ = t²₀.₉₇₅(dof) · s²``
    The optimum's misfit and the threshold: a value ``v`` of ``q`` lies in the 95 %
    interval where ``min{RSS(x) : q(x) = v} − RSS* ≤ Δ`` (the F-test of one parameter;
    for a linear model the profile interval is the delta-method one exactly).
``η``
    The step ``v − q*`` of a side; ``ρ = ΔRSS/Δ`` where it ends.

One side
--------
Its first step is the linear interval's end (a small share of the range where the linear
interval has none or is blind, twice the farthest known point under the threshold where
that lies beyond). The constrained minimum at ``q = v`` (:meth:`Profiler._refit`): the last
point moved onto ``q = v`` along ``g = ∂q/∂x`` (algebra, no runs), then Gauss–Newton
steps within the constraint's tangent plane (``g·d = 0``), each moved back onto it; the
Jacobian is the optimum's, updated by Broyden's rule at each point (no differences: a run
a condition group an evaluation, ``NUISANCE_EVALUATIONS`` at most). A re-fit over the
threshold is judged so only once it has settled: after a Gauss–Newton step from its linear
prediction, until a step no longer halves its ``ρ`` or ``OVER_EVALUATIONS`` are spent (its
``ρ`` bounds the profile's from above; the prediction alone can be far off along the
valley of equally good coats). The one place with differences: on a side the optimum's
linearisation is blind to, a re-fit from a flat start left over the threshold takes them
for the columns the curves did not see (Broyden's rule learns a column only along the steps
taken), until they come out unseen again on that side. Where ``ρ`` lies within
``AGREES`` the end is found — at the first step, the linear interval stands (``method``
``linear``); else the next ``η`` by the secant rule on ``√ΔRSS`` (between
bracketing steps, by interpolation), at most ``MAX_STEPS``. A side whose step at the end
of the quantity's range still lies under the threshold is *open*: the curves do not
bound it there. So is a side whose end a bound holds, not the curves: where the re-fit's
Gauss–Newton model with that bound lifted falls under the threshold
(:meth:`Profiler._walled`; the study file's ranges are then what to widen).

A profile point whose RSS lies more than ``BETTER_CHI2 · s²`` below the optimum's is
another basin (``better``): the calibration fits again from there.

What each side bounds, ``kind``: ``two-sided``, ``lower-bound`` (the upper side open),
``upper-bound``, ``free`` (both open).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import lsq_linear

from ..study._space import ParameterSpec
from ._determination import determination_threshold, interval_kind_of
from ._local import BudgetSpent, LocalFit, ResidualModel, broyden_update

__all__ = [
    "AGREES",
    "Profile",
    "ProfileSide",
    "Quantity",
    "end_value",
    "profile",
    "projected",
]

_LOG = logging.getLogger(__name__)

AGREES = (0.8, 1.25)  # ΔRSS/Δ at a side's end: found (the end within ~±10 % of its step)
LINEAR_HOLDS = (0.95, 1.25)  # …and the linear end stands as it is (else moved out, ρ < 1)
NUISANCE_EVALUATIONS = 3  # residual evaluations of one constrained re-fit
FIRST_EVALUATIONS = 2  # …of a side's first (the linear end's check)
FAR_OVER = 25.0  # a re-fit this far over the threshold (ρ) after a step that no longer
# halved it: no more steps
PIN_UNIT = 1e-4  # a parameter this near a bound (share of its range) is held by it
FLAT = 0.1  # ρ under this where a side the linearisation is blind to starts: its re-fits relearn
RANGED = 0.25  # ρ under this up to where a range holds the step over: the ranges end the side
# (FLAT before: a side whose every re-fit had Ecoat held at its bound paid ρ 0.107 all along,
# the curves blind to Mp — ended on one machine, open on another)
# sides the curves see at every coat: D's (the elastic rise) and Mp's lower one (a coat of a
# smaller plastic moment yields sooner) — the ranges never end them; a steep rise there is
# the curves' (a 5 mm test's coat: ρ 0.22 at −5.1 % in Mp, 12.9 at −5.6 %, a range holding
# both, had been stated "no bound on Mp within the ranges")
ALWAYS_SEEN = frozenset(
    {("bending_stiffness_nmm", -1.0), ("bending_stiffness_nmm", 1.0), ("plastic_moment_n", -1.0)}
)
FLAT_RISE = 1.25  # …or ρ risen no more than this from half the way out (a quadratic rise: 4 ×)
FLAT_NEAREST = 1.2  # …or from nearer, as little as 1/1.2 of the way in: by that ratio^0.32
RISEN = 0.25  # an unchecked side's end stands where its re-fits rose at least this share of a
# quadratic rise to it (√ρ half as fast): else nothing the profile saw bounds it there
OPEN_PRECISION = 0.1  # …found to within this share of the quantity's range
CONFIRM = 2.0  # an end is confirmed by a re-fit this much farther out…
CONFIRM_RATIO = 2.0  # …whose ρ reaches this (a quadratic rise gives 4): else it was roughness
CONFIRM_EVALUATIONS = 2  # …its linear prediction and one Gauss–Newton step (OVER_AFTER_STEPS)
OVER_AFTER_STEPS = 1  # a re-fit is judged over the threshold only after this many Gauss–Newton
# steps from its linear prediction: that prediction, from a Jacobian the runs so far updated,
# can be far off along the valley of equally good coats (seen: ρ 116 at Ecoat +1.5 %, the
# profile there ρ < 0.01, Ecoat's interval ±0.5 % with the truth 131 % above)…
DESCENDING = 0.5  # …and only once a step no longer lowers ρ below this share of the last's…
OVER_EVALUATIONS = 3  # …or after this many evaluations (6: the same intervals, 0.2 % more runs)
RELEARNED_EVALUATIONS = 6  # …or this many after fresh columns (:meth:`Profiler._refit`)
END_PRECISION = 0.1  # a bracket this narrow (share of its far step): the end, the far step
MAX_STEPS = 8  # constrained re-fits of one side, at most
POLISH_BELOW = 3.0  # a re-fit with ρ from AGREES[0] to this takes a fresh Jacobian and steps on
POLISHES = 2  # …at most this many times a side, where it reached within this share of the
POLISH_SHARE = 0.05  # quantity's range (a narrow statement: where an unsettled re-fit misleads)
# — not the linear end's own check, which its confirmation tests; and, anywhere, a re-fit
# over the threshold that took a modulus off the bound holding it at the optimum
# (:meth:`Profiler._unheld`)
LEAP_POLISHES = 4  # a confirmation that leaps (ρ > FAR_OVER, no range holding it) is re-fitted
# from a fresh Jacobian while each time at least halves its ρ (DESCENDING), at most this many
# times: settled, it is judged; still falling, it confirms nothing (cover-164 of 240: 3 times
# from 1.5·10⁶ to 1.33, a rise less than quadratic; cover-185: 8.6·10⁴, 856, 1.05, 0.06, under
# the threshold; cover-120: 318, 316, a rise)
BETTER_CHI2 = 1.0  # a profile point this many s² below the optimum: another basin
TRUST = 0.2  # a re-fit's Gauss–Newton step moves no coordinate farther than this
DAMPING = 1e-8  # of ‖J‖²: the re-fit's Gauss–Newton steps, damped
ONTO_STEPS = 4  # Newton's steps onto the constraint (algebra)
ONTO_TOLERANCE = 1e-6  # …until q is this share of its range near its target
OPEN_UNIT = 1e-3  # a step within this share of the quantity's range of its end: at the end
FD_STEP_Q = 1e-6  # differences of q(x) (algebra, no runs)
LINEAR_BLIND = 0.5  # a linear end this share of the range away: the linearisation is blind
FIRST_UNSEEN = 0.05  # the first step of a side the curves do not see at the optimum: this
# share of the quantity's range (a coat's plastic moment where none yields: zero slope there)
NULL_SINGULAR = 1e-3  # a singular value of J below this share of the largest: not seen by
# the linear prediction of a re-fit (the valley of equally good coats: its 1e-5 share of a
# well-determined Mp's gradient, the differences' noise, had sent the prediction along it)
UNSEEN_SHARE = 0.1  # …and a share of g² this large along such directions: moved along them


@dataclass(frozen=True)
class Quantity:
    """A quantity to profile: its name (a JSON key), the function of the parameters
    (declared units) it is, whether it is log-scaled, and its range over the box
    (``low``, ``high``: the ends of the declared ranges for a parameter)."""

    name: str
    value: Callable[[np.ndarray], float]
    log: bool
    low: float
    high: float

    def scaled(self, theta: np.ndarray) -> float:
        """``q`` at parameters ``theta``: in the declared scale."""
        return self.scale(self.value(theta))

    def scale(self, value: float) -> float:
        return math.log(value) if self.log else value

    def unscaled(self, q: float) -> float:
        return math.exp(q) if self.log else q

    @property
    def range_scaled(self) -> tuple[float, float]:
        return (math.log(self.low), math.log(self.high)) if self.log else (self.low, self.high)


_ANY = Quantity("", lambda theta: 0.0, False, 0.0, 1.0)  # a point judged for no quantity


@dataclass(frozen=True)
class ProfileSide:
    """One side of a profile interval.

    ``end`` is the quantity's value where the re-fit reaches the threshold (declared
    units), None where the side is *open* (its range end fits under the threshold;
    ``point`` is then the re-fit at that end); ``method`` ``linear`` where the linear
    interval's end was checked and stands, ``profile`` where the re-fits placed it,
    ``unchecked`` where the budget stopped the profile before it did, a re-fit could not
    reach its target, or a parameter's re-fit leapt over the threshold beyond a flat stretch
    (:func:`_leap`) — the linear end (or the nearest step over) then stands, unchecked, where
    the re-fits rose towards it; open where they found the misfit flat, where there is none,
    or where that step leapt as well (far over, farther out, no range holding it);
    ``ratio`` is ``ΔRSS/Δ`` at ``point``; ``steps`` the
    re-fits made; ``point`` the parameters of the last re-fit (an alternative fit the
    data hardly tell from the optimum: what a next test should separate)."""

    end: float | None
    method: str
    ratio: float | None
    steps: int
    point: np.ndarray | None


@dataclass(frozen=True)
class Profile:
    """The profile interval of one quantity: ``value`` at the optimum, its two sides,
    and ``kind``."""

    name: str
    value: float
    lower: ProfileSide
    upper: ProfileSide

    @property
    def kind(self) -> str:
        return interval_kind_of(self.lower.end is not None, self.upper.end is not None)

    @property
    def method(self) -> str:
        """``profile`` where a re-fit placed either end, ``linear`` where the linear ends
        were checked and stand, ``unchecked`` where a side was not checked."""
        methods = {self.lower.method, self.upper.method}
        return next(m for m in ("unchecked", "profile", "linear") if m in methods)


@dataclass(frozen=True)
class _Step:
    """One re-fit of a side: how far it reached (``size``, ``|q − q*|``), ``ρ``, the point
    and the Jacobian there, whether a range holds it."""

    size: float
    ratio: float
    x: np.ndarray
    jac: np.ndarray
    held: bool

    def point(self, profiler: Profiler) -> np.ndarray:
        return profiler.model.point(self.x)


@dataclass
class _Optimum:
    """The optimum a profile starts from, in fit coordinates."""

    x: np.ndarray
    rss: float
    jacobian: np.ndarray  # ∂r/∂x at x
    threshold: float  # Δ
    sigma2: float  # s²
    pinned: np.ndarray  # (p,) bool: each parameter held by a bound at x (:func:`_pinned`)


class Profiler:
    """Profiles of quantities about a converged local fit, with the runs of ``model``.

    Parameters
    ----------
    model : ResidualModel
        ``r(x)`` through the (cheapest exact-enough) solver, with its budget.
    fit : LocalFit
        The converged optimum; its ``at_bound`` counts the free parameters.
    """

    def __init__(self, model: ResidualModel, fit: LocalFit) -> None:
        self.model = model
        x = model.pin(fit.theta)
        residual = model.residual(x)
        rss = float(residual @ residual)
        dof = max(residual.size - int(np.sum(np.asarray(fit.at_bound) == 0)), 1)
        threshold = determination_threshold(rss, dof)
        pinned = _pinned(model.coordinates.to_unit(x))
        self.optimum = _Optimum(x, rss, model.jacobian(x), threshold, rss / dof, pinned)
        self.better: np.ndarray | None = None  # a point below the optimum: another basin
        self.seen: list[_Step] = []  # every re-fit so far (of any quantity)
        self.shared = 0  # of them, told another profiler (:func:`_share`)

    def know(self, points: Sequence[np.ndarray]) -> None:
        """Parameter points whose runs are done (no new runs: the result cache holds
        them) judged like re-fits and kept in ``seen``: each one under the threshold is in
        the region, whatever a profile from the optimum reaches."""
        for theta in points:
            x = self.model.pin(np.asarray(theta, dtype=float))
            self._step(_ANY, 0.0, 1.0, x, self.optimum.jacobian)

    def profile(self, quantity: Quantity, linear: tuple[float | None, float | None]) -> Profile:
        """Both sides of ``quantity``'s interval; ``linear``: the linear interval's ends
        (declared units; None where it has none: the first step is then the range's end)."""
        theta = self.model.point(self.optimum.x)
        sides = [self._side(quantity, sign, linear[k]) for k, sign in enumerate((-1.0, 1.0))]
        return Profile(quantity.name, quantity.value(theta), sides[0], sides[1])

    def revisited(self, quantity: Quantity, found: Profile) -> Profile:
        """``found`` with each side whose end a point of the region contradicts — one under
        the threshold beyond it, found by a later profile — profiled again from there (the
        side starts from the farthest such point)."""
        q0 = quantity.scaled(self.model.point(self.optimum.x))
        sides = [found.lower, found.upper]
        for k, sign in enumerate((-1.0, 1.0)):
            end = sides[k].end
            if end is None:
                continue
            beyond = self._farthest_under(quantity, q0, sign)
            if beyond.size > sign * (quantity.scale(end) - q0):
                _LOG.debug("%s: a point under the threshold lies beyond %.6g", quantity.name, end)
                sides[k] = self._side(quantity, sign, None)
        return Profile(found.name, found.value, sides[0], sides[1])

    # -- one side ------------------------------------------------------------------------------
    def _side(self, quantity: Quantity, sign: float, linear_end: float | None) -> ProfileSide:
        """One side of ``quantity``'s interval (``sign`` −1 lower, +1 upper): the bracket of
        steps under and over the threshold narrowed until a step's ``ρ`` lies within
        ``AGREES``, or the bracket is within ``END_PRECISION`` of its far end (the end: the
        step over, the wider; open where the ranges end it, :meth:`_bracketed`), or the
        side is open — its range end under the threshold, or no step over it within
        ``MAX_STEPS``.

        Every point the profiles found under the threshold is in the 95 % region: the
        farthest of them along ``q`` starts the bracket (a side it reaches the range end
        of costs no run)."""
        optimum = self.optimum
        q0 = quantity.scaled(self.model.point(optimum.x))
        span = abs(np.diff(quantity.range_scaled)[0])
        far = abs(quantity.range_scaled[1 if sign > 0 else 0] - q0)  # |η| of the range's end
        under = self._farthest_under(quantity, q0, sign)
        if far - under.size <= OPEN_UNIT * span:
            return ProfileSide(None, "profile", under.ratio, 0, under.point(self))
        size = far if linear_end is None else min(abs(quantity.scale(linear_end) - q0), far)
        relearn = linear_end is None or size >= LINEAR_BLIND * span
        if relearn:  # the linearisation sees little of it: small steps first
            linear_end, size = None, min(far, FIRST_UNSEEN * span)
        if size <= under.size:  # a point under the threshold lies beyond the linear end
            linear_end, size = None, min(far, 2.0 * under.size)  # (the first step is not it)
        over: _Step | None = None  # the nearest over it
        interpolated = False  # whether the last step was placed by interpolation
        pending: tuple[_Step, str] | None = None  # an end, and how it was found, to confirm
        polishes = 0
        unders: list[_Step] = []  # this side's re-fits under the threshold
        held_over = True  # every re-fit over the threshold so far had a range holding it
        # a leap far over the threshold is the physics only where the curves see the side at
        # every coat (ALWAYS_SEEN); elsewhere a re-fit that could not follow a trade
        leaps = not _always_seen(quantity, sign)
        for step in range(1, MAX_STEPS + 1):
            try:  # from the farthest point under the threshold: a good fit, a good Jacobian
                evaluations = (
                    CONFIRM_EVALUATIONS
                    if pending is not None
                    else FIRST_EVALUATIONS
                    if step == 1
                    else NUISANCE_EVALUATIONS
                )
                x, jac, learned = self._refit(
                    quantity,
                    q0 + sign * size,
                    under.x,
                    under.jac,
                    evaluations,
                    relearn and under.ratio < FLAT,
                )
            except BudgetSpent:
                return self._unfinished(quantity, q0, sign, linear_end, under, over, step)
            relearn = relearn and learned is not False  # …until the columns stay unseen
            found = self._step(quantity, q0, sign, x, jac)
            self._log(quantity, sign, step, size, far, found)
            linear_check = step == 1 and linear_end is not None and found.ratio <= AGREES[1]
            raw = found  # (before a polish)
            if (
                polishes < POLISHES
                and pending is None
                and not linear_check
                and (
                    (AGREES[0] <= found.ratio <= POLISH_BELOW and found.size <= POLISH_SHARE * span)
                    or (found.ratio > AGREES[1] and self._unheld(found.x))
                )
            ):
                polished = self._polished(quantity, q0 + sign * size, q0, sign, found)
                # a polish that lowered nothing (or that the budget refused): polish no more
                polishes = polishes + 1 if polished is not found else POLISHES
                found = polished
                self._log(quantity, sign, step, size, far, found)
            held_over = held_over and (found.ratio <= AGREES[1] or found.held)  # (polished)
            # a leap — or one a polish brought down but not under the threshold, which has
            # not settled either (cover-089 of 240, with the upper bounds' differences held
            # to rounding, tried: k_s ρ 714 at −0.148, polished to 2.3; 0.71 at every step
            # to −0.137, and without them 0.45 at the range's end, a re-fit from the optimum)
            if (
                leaps
                and pending is None
                and (
                    _leap(found, under, unders)
                    or (found.ratio > AGREES[1] and _leap(raw, under, unders))
                )
            ):
                if over is not None and _far_unheld(over) and over.size > found.size:
                    # a step over farther out, as far over (ρ > FAR_OVER) and no range
                    # holding it, is a re-fit that could not follow the trade either: no end,
                    # nor the linear end it checked (cover-212 of 240: k_s ρ 4,388 at −0.010,
                    # 0.11 at −0.004, 948 at −0.007; "k_s ≥ 0.014" stated, the truth 0.0089
                    # at ρ 0.11 with every other parameter its own)
                    over, linear_end = None, None
                return self._unfinished(quantity, q0, sign, linear_end, under, over, step)
            if found.size <= min(under.size, (1 - OPEN_UNIT) * size) and (
                found.ratio <= AGREES[1] or pending is None
            ):
                # the re-fit fell back short of its target, to where a point under the
                # threshold lies: it did not reach the constraint, and says nothing of the side
                # there (over the threshold too: cover-056 of 240, study seed 1, fell back to
                # the optimum's Tcoat at ρ > 1, an "end" at the fit's own value) — but a
                # confirmation over the threshold confirms its end wherever it stopped
                return self._unfinished(quantity, q0, sign, linear_end, under, over, step + 1)
            if pending is not None:  # ``found`` is the step beyond an end: does it rise on?
                end, how = pending
                pending = None
                if leaps and found.size > end.size and _far_unheld(found):
                    # a leap beyond the end: a rise, or a re-fit that could not follow the
                    # trade? Re-fitted from fresh Jacobians until it settles (cover-164 of 240:
                    # k_s ρ 0.59 at −0.082, 1.10 at −0.084, 1.5·10⁶ at −0.099, the range's
                    # end, polished to 609, 15, 1.33; the truth, −0.096, fits at ρ ≤ 0.15)
                    found, settled = self._settled(quantity, q0 + sign * size, q0, sign, found)
                    self._log(quantity, sign, step, size, far, found)
                    if not settled or found.size <= end.size:
                        # still falling (or the budget stopped it, or it fell back short of
                        # the step): the side is not checked beyond the end — the nearest step
                        # over stands, unchecked, unless it leapt as well (as for a leap found
                        # last, above)
                        if over is not None and _far_unheld(over):
                            over, linear_end = None, None
                        return self._unfinished(
                            quantity, q0, sign, linear_end, under, over, step + 1
                        )
                if found.size > end.size and AGREES[1] < found.ratio < end.ratio / CONFIRM_RATIO:
                    # over the threshold, and beyond the end it was to confirm at less than
                    # half its ρ: the misfit falls beyond it, its re-fit had not settled (cover-046
                    # of 240, with the upper bounds' differences held to rounding, tried:
                    # Tcoat's re-fit at +0.115 in log Tcoat drove Scoat onto its
                    # bound at ρ 111, the step at +0.230 lay at ρ 16.5, the truth, at
                    # +0.505, fits at ρ 0.21) — the side is not checked beyond it
                    return self._unfinished(quantity, q0, sign, None, under, None, step + 1)
                if found.ratio >= CONFIRM_RATIO:
                    return self._accepted(quantity, q0, sign, end, how, linear_end, step)
                if found.ratio > AGREES[1]:  # it rises, less than a quadratic: the wider end
                    return self._ended(quantity, q0, sign, found, step)
                over = None  # rough, not an end: under the threshold beyond it
            if found.ratio <= AGREES[1]:
                if AGREES[0] <= found.ratio and pending is None and not self._beyond(found, under):
                    how = "linear" if step == 1 and linear_end is not None else "profile"
                    pending, size = (found, how), min(far, CONFIRM * found.size)
                    if size <= (1.0 + OPEN_UNIT) * found.size:  # at the range's end
                        return self._accepted(quantity, q0, sign, found, how, linear_end, step)
                    continue
                if far - found.size <= OPEN_UNIT * span:
                    return ProfileSide(None, "profile", found.ratio, step, found.point(self))
                unders.append(found)
                under = found if found.size > under.size else under
            elif over is None or found.size < over.size:
                over = found
            if over is not None and self._unsettled_under(quantity, sign, under, over, unders):
                polished = self._polished(quantity, q0 + sign * under.size, q0, sign, under)
                polishes = polishes + 1 if polished is not under else POLISHES
                if polished is not under and polished.ratio <= AGREES[1]:
                    unders = [polished if u is under else u for u in unders]
                    # (it may reach an ulp short of the target, or onto it within
                    # ONTO_TOLERANCE or OPEN_UNIT of it: the same step, not a fall back)
                    short = max(OPEN_UNIT * under.size, ONTO_TOLERANCE * span)
                    reached = polished.size >= under.size - short
                    under = polished if reached else under
            if over is not None:
                width = over.size - under.size
                if _ranged(quantity, sign, under, over, unders) and width <= OPEN_PRECISION * span:
                    return ProfileSide(None, "profile", under.ratio, step, under.point(self))
                if width <= END_PRECISION * over.size:
                    pending, size = (over, "profile"), min(far, CONFIRM * over.size)
                    continue
            size, interpolated = self._next_size(under, over, far, interpolated)
        if over is None:  # not closed by the curves within the steps
            return ProfileSide(None, "profile", under.ratio, MAX_STEPS, under.point(self))
        if leaps and _leap(over, under, unders):
            # the steps ran out with the one over a leap from the flat stretch they walked
            # (cover-104 of 240: k_s ρ 0.20–0.23 at every step to −0.0049, 285 at −0.0057
            # where the truth, −0.0061, fits at 0.28): no end, as for a leap found last
            return self._unfinished(quantity, q0, sign, None, under, None, MAX_STEPS + 1)
        return self._bracketed(quantity, q0, sign, under, over, MAX_STEPS, unders, held_over)

    def _cornered(self, quantity: Quantity, sign: float, under: _Step, held_over: bool) -> bool:
        """Whether the ranges end a side at the optimum itself: it holds a parameter at a
        bound, no re-fit of the side lies under the threshold, and a range held every one
        over it, down to the smallest step — the box's corner, not the curves (0.6/0.35/0.02
        at 10 mm, noise seed 500, fitted with Scoat at its bound 0.4 and Ecoat 0.5 % above
        its own: Mp one step of 1 % above, with Tcoat up and Ecoat at its bound, raised D; Mp
        had been stated 4.22–11.4 where the curves bound it from below only). Never on a
        side the curves see at every coat (``ALWAYS_SEEN``)."""
        span = abs(float(np.diff(quantity.range_scaled)[0]))
        return (
            not _always_seen(quantity, sign)
            and under.size <= 1e-9 * span  # (the optimum, or a known point at it)
            and held_over
            and bool(np.any(self.optimum.pinned))
        )

    def _walled(self, quantity: Quantity, q0: float, sign: float, end: _Step) -> bool:
        """Whether a bound, not the curves, holds ``end`` (a re-fit at or over the threshold
        that would end a side): a coordinate at a face of the box (a parameter at its bound,
        a held modulus in its own unit coordinate; the quantity's own excepted), and the
        Gauss–Newton model of the re-fit at the same ``q`` with those faces lifted rises so
        little from the same model at the optimum's ``q`` (where the re-fit within the box
        is at ``AGREES[0]`` or over) that a quadratic rise would meet the threshold only
        beyond the quantity's range — the bound's multiplier carries the rise (algebra: the
        residuals and Jacobians are the re-fit's and the optimum's own). The faces are
        those of the profile's own coordinates (a modulus held in its own unit coordinate
        is one; in the fit coordinates its bound is a kink, and :meth:`_cornered` asks).
        A bound that carries part of the rise moves the end out but does not open it
        (cover-239 of 240: k_e's re-fits at ±0.1 % ρ 1.03 and 0.98 within the box, 0.75 and
        0.74 with Tcoat's upper bound lifted, −0.26 at the optimum: the curves bound k_e).
        0.6/0.35/0.02 at 10 mm, noise seed 500, OpenBLAS's Haswell kernels on an AVX2 host:
        a fit with Ecoat at its lower bound and Scoat at its upper one, Mp's upper re-fits
        ρ 0.25, 1.0, 4.0 at +0.028, +0.056, +0.11 % — Tcoat up, so D up — and Mp stated
        4.0–11.37 where a larger Scoat fits as well at any Mp above (lifted: ρ −1.4·10⁻⁴
        at +0.056 %, −1.3·10⁻⁵ at the optimum).
        Never on a side the curves see at every coat (``ALWAYS_SEEN``)."""
        if _always_seen(quantity, sign):
            return False
        far = abs(quantity.range_scaled[1 if sign > 0 else 0] - q0)
        x = end.x
        faces = (x <= PIN_UNIT) | (x >= 1.0 - PIN_UNIT)
        names = self.model.problem.space.names
        if quantity.name in names:
            faces[names.index(quantity.name)] = False
        if not np.any(faces):
            return False

        def ratio(at: np.ndarray, jac: np.ndarray, lifted: np.ndarray | None) -> float:
            """The Gauss–Newton model's ``ρ`` of the re-fit from ``at`` at its own ``q``."""
            residual = self.model.residual(at)  # (evaluated already: no run)
            step = _tangent_step(residual, jac, self._gradient(quantity, at), at, lifted)
            rss = float(np.sum((residual + jac @ step) ** 2))
            return (rss - self.optimum.rss) / self.optimum.threshold

        boxed = ratio(x, end.jac, None)
        lifted = ratio(x, end.jac, faces)
        # lifted at the optimum too: its own pull against a bound is no rise
        start = ratio(self.optimum.x, self.optimum.jacobian, faces)
        _LOG.debug(
            "  %s: ρ %.4g within the box; lifted %.4g, %.4g at the optimum",
            quantity.name,
            boxed,
            lifted,
            start,
        )
        return AGREES[0] <= boxed and lifted - start <= (end.size / far) ** 2

    def _opened(self, end: _Step, steps: int) -> ProfileSide:
        """A side a bound holds open (:meth:`_walled`): its re-fit the alternative fit only
        where it lies at the threshold, no farther over (a fit the data hardly tell from
        the optimum, what a next test separates)."""
        point = end.point(self) if end.ratio <= AGREES[1] else None
        return ProfileSide(None, "profile", end.ratio, steps, point)

    def _unsettled_under(
        self, quantity: Quantity, sign: float, under: _Step, over: _Step, unders: list[_Step]
    ) -> bool:
        """Whether the side would be ended by the curves only because its farthest re-fit
        under the threshold had not settled: a range holds the step over, the re-fits reach
        out far enough (:func:`_stretch`), and that re-fit's ``ρ`` alone is over ``RANGED``
        (0.6/0.35/0.02 at 10 mm, noise seed 503, Ecoat held exactly at its bound: Mp's re-fits
        at +0.52 and +0.78 in log Mp kept Tcoat 0.04 % off the fit's and D with it, at ρ 0.75
        each, and Mp was stated two-sided where the curves bound it from below only)."""
        return (
            _range_holds(quantity, sign, under, over)
            and under.ratio >= RANGED
            and not _flat(under, unders)
        )

    def _beyond(self, found: _Step, under: _Step) -> bool:
        """Whether a point under the threshold lies beyond ``found`` already (its end is then
        roughness of the misfit, not the region's edge)."""
        return under.size > found.size

    def _accepted(
        self,
        quantity: Quantity,
        q0: float,
        sign: float,
        end: _Step,
        how: str,
        linear_end: float | None,
        steps: int,
    ) -> ProfileSide:
        """An end whose step beyond rose on: the linear end where the first step checked
        it (``ρ`` within ``LINEAR_HOLDS``), else where the re-fit placed it — moved out to
        where a quadratic rise would meet the threshold where it lay under it (``ρ < 1``:
        the re-fit's ``ρ`` is at most what its nuisance parameters allow, never less, so
        only the outward move is safe). Open where a bound, not the curves, holds the end
        (:meth:`_walled`)."""
        if self._walled(quantity, q0, sign, end):
            return self._opened(end, steps)
        if how == "linear" and LINEAR_HOLDS[0] <= end.ratio <= LINEAR_HOLDS[1]:
            assert linear_end is not None  # a first step at the linear end
            value = end_value(quantity, q0, sign, abs(quantity.scale(linear_end) - q0))
            return ProfileSide(value, "linear", end.ratio, steps, end.point(self))
        size = end.size / math.sqrt(end.ratio) if 0.0 < end.ratio < 1.0 else end.size
        far = abs(quantity.range_scaled[1 if sign > 0 else 0] - q0)
        value = end_value(quantity, q0, sign, min(size, far))
        return ProfileSide(value, "profile", end.ratio, steps, end.point(self))

    def _bracketed(
        self,
        quantity: Quantity,
        q0: float,
        sign: float,
        under: _Step,
        over: _Step,
        steps: int,
        earlier: Sequence[_Step] = (),
        held_over: bool = False,
    ) -> ProfileSide:
        """The side ended between a point under the threshold and one over it: at the one
        over (the wider interval) — or open where the misfit was flat up to where a range
        holds the one over (a parameter at a bound the optimum was not at, :func:`_ranged`):
        there the ranges end it, not the curves (Tcoat along the valley of equally good
        coats, until Ecoat reaches its bound); or where they end it at the optimum itself
        (``held_over``: a range held every step over, :meth:`_cornered`)."""
        if _ranged(quantity, sign, under, over, earlier) or self._cornered(
            quantity, sign, under, held_over
        ):
            return ProfileSide(None, "profile", under.ratio, steps, under.point(self))
        return self._ended(quantity, q0, sign, over, steps)

    def _ended(
        self, quantity: Quantity, q0: float, sign: float, found: _Step, steps: int
    ) -> ProfileSide:
        """The side ended at ``found`` (open where that is the range's end, or where a bound,
        not the curves, holds it: :meth:`_walled`)."""
        if self._walled(quantity, q0, sign, found):
            return self._opened(found, steps)
        end = end_value(quantity, q0, sign, found.size)
        return ProfileSide(end, "profile", found.ratio, steps, found.point(self))

    def _unfinished(
        self,
        quantity: Quantity,
        q0: float,
        sign: float,
        linear_end: float | None,
        under: _Step,
        over: _Step | None,
        step: int,
    ) -> ProfileSide:
        """A side the budget stopped, or whose re-fit could not reach its target:
        ``unchecked``, its end the nearest step over the threshold where one was made, else
        the linear end where no point under the threshold lies beyond it, else open — and
        open where the side's own re-fits contradict that end: the misfit at the farthest
        point under the threshold less than ``RISEN`` of what a quadratic rise to the end
        gives there (cover-075 of 120: "Scoat ≥ 0.239", from a first re-fit at the linear
        end that had not settled, ρ 2.6·10⁶, with ρ 4·10⁻⁴ at 0.25 and the truth, 0.213,
        fitting as well; the end is then a guess, and the side is stated open)."""
        end: float | None = None
        if over is not None and over.size > under.size:
            end = end_value(quantity, q0, sign, over.size)
        elif linear_end is not None and abs(quantity.scale(linear_end) - q0) > under.size:
            end = end_value(quantity, q0, sign, abs(quantity.scale(linear_end) - q0))
        if end is not None and under.size > 0.0:
            size = abs(quantity.scale(end) - q0)
            if under.ratio < RISEN * (under.size / size) ** 2:
                end = None
        return ProfileSide(end, "unchecked", None, step - 1, under.point(self))

    def _unheld(self, x: np.ndarray) -> bool:
        """Whether ``x`` has a modulus off the bound that held it at the optimum (in the fit
        coordinates, where that bound is a kink): the Jacobian a re-fit carries from there
        is the held side's differences, no model of the side it moved to — a re-fit of
        Tcoat from a coat held at Ecoat's bound leapt to ρ 10⁵ along the valley where a
        fresh Jacobian finds ρ < 0 (cover-056 of 240, Haswell kernels)."""
        coordinates = self.model.coordinates
        moduli = coordinates.sectioned()
        held = self.optimum.pinned[moduli]
        return bool(np.any(held & ~_pinned(coordinates.to_unit(x))[moduli]))

    def _farthest_under(self, quantity: Quantity, q0: float, sign: float) -> _Step:
        """Of the optimum and every point the profiles found under the threshold, the one
        farthest along ``sign · q``."""
        best = _Step(0.0, 0.0, self.optimum.x, self.optimum.jacobian, False)
        for seen in self.seen:
            reach = sign * (quantity.scaled(self.model.point(seen.x)) - q0)
            if seen.ratio < AGREES[0] and reach > best.size:
                best = _Step(reach, seen.ratio, seen.x, seen.jac, False)
        return best

    def _step(
        self, quantity: Quantity, q0: float, sign: float, x: np.ndarray, jac: np.ndarray
    ) -> _Step:
        """A re-fit's point judged: how far it reached, its ``ρ``, whether a range holds it
        (a parameter at a bound that the optimum was not at, the profiled one aside); kept
        in ``seen``, and as ``better`` where it lies below the optimum."""
        optimum, model = self.optimum, self.model
        residual = model.residual(x)
        delta = float(residual @ residual) - optimum.rss
        point = model.point(x)
        if delta < -BETTER_CHI2 * optimum.sigma2:
            self.better = point
        pinned = _pinned(self.model.coordinates.to_unit(x)) & ~optimum.pinned
        if quantity.name in model.problem.space.names:
            pinned[model.problem.space.names.index(quantity.name)] = False
        reached = max(sign * (quantity.scaled(point) - q0), 0.0)
        found = _Step(reached, delta / optimum.threshold, x, jac, bool(np.any(pinned)))
        self.seen.append(found)
        return found

    def _log(
        self, quantity: Quantity, sign: float, step: int, size: float, far: float, found: _Step
    ) -> None:
        _LOG.debug(
            "profile of %s, %s side, step %d: |η| %.4g reached %.4g (range end %.4g), ρ %.4g%s",
            quantity.name,
            "upper" if sign > 0 else "lower",
            step,
            size,
            found.size,
            far,
            found.ratio,
            ", a range holds it" if found.held else "",
        )

    def _next_size(
        self, under: _Step, over: _Step | None, far: float, interpolated: bool
    ) -> tuple[float, bool]:
        """The next |η|, and whether interpolation placed it: beyond the farthest step under
        the threshold by the secant rule (``√ΔRSS ∝ |η|``, at least twice as far) where none
        is over it; else between the two — by interpolation of ``√ΔRSS``, and halfway after
        an interpolated step that did not end it (a steep rise, such as a coat starting to
        yield, makes interpolation creep) or where a range holds the one over."""
        if over is None:
            if under.ratio <= 0.0:
                return min(far, max(4.0 * under.size, 1e-6)), False
            return min(far, max(under.size / math.sqrt(under.ratio), 2.0 * under.size)), False
        if interpolated or over.held:  # a range holds the one over: no slope to follow
            return 0.5 * (under.size + over.size), False
        low, high = math.sqrt(max(under.ratio, 0.0)), math.sqrt(over.ratio)
        share = (1.0 - low) / (high - low) if high > low else 0.5
        return under.size + min(max(share, 0.1), 0.9) * (over.size - under.size), True

    def _refit(
        self,
        quantity: Quantity,
        target: float,
        start: np.ndarray,
        jac: np.ndarray,
        evaluations: int,
        relearn: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, bool | None]:
        """The constrained re-fit at ``q = target``: ``start`` moved onto the constraint
        (:meth:`_onto`), then Gauss–Newton steps of every coordinate within the
        constraint's tangent plane, each moved back onto it; at every point evaluated the
        Jacobian of ``r`` is updated by Broyden's rule (no differences). A step that did
        not lower the RSS is halved once. A re-fit over the threshold is judged so only
        after a Gauss–Newton step from the linear prediction (``OVER_AFTER_STEPS``), and
        only once a step no longer halves its ``ρ`` (up to ``OVER_EVALUATIONS``): its ``ρ``
        bounds the profile's from above, so an end or a confirmation it makes must come
        from a re-fit that has settled, or spent ``OVER_EVALUATIONS``. An overshot step's
        half is evaluated within that limit too.

        ``relearn`` (a side the optimum's linearisation is blind to, from a start where the
        misfit is flat): a re-fit left over the threshold takes fresh differences of the
        columns of ``J`` the curves did not see (:meth:`_stale_columns`) and steps on from
        its best point. Broyden's rule learns a column only along the steps taken: where no
        curve of the optimum reaches its plateau, ``∂r/∂log Mp`` is zero there and stays so,
        while lowering the tension's ``k_s`` brings a plateau in the tensioned curves that a
        larger Scoat takes away (cover-005 of 240: ``k_s ≥ 0.0098`` stated, the truth 0.0048
        with its misfit 0.59 of the threshold above the fit's).

        The evaluated point of lowest RSS, the Jacobian, and whether fresh columns were seen
        (None: none taken; False: they stayed unseen, and the side takes none again)."""
        model = self.model
        gap = target - quantity.scaled(model.point(start))
        shift = _linear_shift(jac, self._gradient(quantity, start), gap)
        x = self._onto(quantity, np.clip(start + shift, 0.0, 1.0), target, jac)
        best, ratio, jac = self._descend(quantity, target, x, start, jac, evaluations)
        if not relearn or ratio <= AGREES[1]:
            return best, jac, None
        stale = self._stale_columns(quantity, best, jac)
        if not stale:
            return best, jac, None
        jac = jac.copy()  # columns the curves did not see where the side began: seen here?
        jac[:, stale] = model.columns(best, stale)  # (a run each)
        learned = self._stale_columns(quantity, best, jac) != stale
        _LOG.debug("  stale columns %s relearned: %s", stale, learned)
        if not learned:
            return best, jac, False
        step = _tangent_step(model.residual(best), jac, self._gradient(quantity, best), best)
        x = self._onto(quantity, best + step, target, jac)
        again, ratio_again, jac = self._descend(
            quantity, target, x, best, jac, OVER_EVALUATIONS, RELEARNED_EVALUATIONS
        )
        return (again if ratio_again < ratio else best), jac, True

    def _polished(
        self,
        quantity: Quantity,
        target: float,
        q0: float,
        sign: float,
        found: _Step,
        refused: bool = False,
    ) -> _Step:
        """``found`` re-fitted on from a fresh Jacobian (differences: a run a condition group
        a coordinate): near the threshold, a re-fit whose Jacobian only Broyden's rule
        updated along the side can stop far from settled — cover-107 of 240 stated
        ``k_s ≤ 0.00938`` at ρ 1.14 where a full constrained fit gives 0.32, and its truth
        0.00939 lies at 0.51. Where the budget cannot finish it (a Jacobian that would not
        fit is not begun), ``found`` stands (``refused``: :class:`BudgetSpent` is raised)."""
        try:
            self.model.check_jacobian_fits(self.model.coordinates.to_unit(found.x))
            jac = self.model.jacobian(found.x)
            step = _tangent_step(
                self.model.residual(found.x), jac, self._gradient(quantity, found.x), found.x
            )
            x = self._onto(quantity, found.x + step, target, jac)
            best, ratio, jac = self._descend(quantity, target, x, found.x, jac, OVER_EVALUATIONS)
            if ratio >= found.ratio:
                return found
            return self._step(quantity, q0, sign, best, jac)
        except BudgetSpent:
            if refused:
                raise
            return found

    def _settled(
        self, quantity: Quantity, target: float, q0: float, sign: float, found: _Step
    ) -> tuple[_Step, bool]:
        """``found`` :meth:`_polished` while each polish at least halves its ``ρ``
        (``DESCENDING``), at most ``LEAP_POLISHES`` times, and whether it settled: a polish
        lowered it by less, or nothing, or brought it under the threshold — not to it, which
        a re-fit still falling passes on its way (cover-185 of 240: Tcoat's confirmation
        8.6·10⁴, 856, 1.05, then 0.06 and 0). Not settled where the budget refused a polish."""
        ratios = [found.ratio]
        settled = False
        try:
            for _ in range(LEAP_POLISHES):
                polished = self._polished(quantity, target, q0, sign, found, refused=True)
                halved = polished.ratio < DESCENDING * found.ratio
                found = polished
                ratios.append(found.ratio)
                if not halved or found.ratio < AGREES[0]:
                    settled = True
                    break
        except BudgetSpent:
            pass
        _LOG.debug(
            "  a leap re-fitted: ρ %s%s",
            " → ".join(f"{r:.3g}" for r in ratios),
            "" if settled else ", not settled",
        )
        return found, settled

    def _descend(
        self,
        quantity: Quantity,
        target: float,
        x: np.ndarray,
        last_x: np.ndarray,
        jac: np.ndarray,
        evaluations: int,
        most: int = OVER_EVALUATIONS,
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """:meth:`_refit`'s Gauss–Newton steps from ``x`` (``last_x``: the point ``jac``
        was last updated at): the evaluated point of lowest RSS, its ``ρ``, the Jacobian
        (``most``: the evaluations a re-fit over the threshold may take while it still
        descends, or to evaluate an overshot step's half)."""
        model = self.model
        last_r = model.residual(last_x)
        best, best_rss, best_ratio, last_ratio = x, math.inf, math.inf, math.inf
        evaluation, allowed = 0, max(evaluations, 1 + OVER_AFTER_STEPS)
        while evaluation < allowed:
            r = model.residual(x)
            evaluation += 1
            if np.any(x != last_x):
                jac = broyden_update(jac, x - last_x, r - last_r)
                last_x, last_r = x, r
            rss = float(r @ r)
            if rss >= best_rss:  # the step overshot: half of it, from the best point
                if evaluation == allowed and allowed < most:
                    allowed += 1  # the half is evaluated: an overshoot is no judgement
                x = self._onto(quantity, 0.5 * (best + x), target, jac)
                continue
            best, best_rss = x, rss
            best_ratio = ratio = (rss - self.optimum.rss) / self.optimum.threshold
            if ratio <= AGREES[1]:
                break  # under the threshold or at it (more steps only lower it)
            stepped = evaluation > OVER_AFTER_STEPS  # judged after a Gauss–Newton step
            descending = ratio < DESCENDING * last_ratio
            last_ratio = ratio
            if stepped and not descending and (ratio > FAR_OVER or evaluation >= evaluations):
                break  # over it, and the last step no longer halved ρ: over it
            if evaluation == allowed and descending and allowed < most:
                allowed += 1  # over it, still descending: not yet judged
            step = _tangent_step(r, jac, self._gradient(quantity, x), x)
            if np.max(np.abs(step)) < 1e-9:
                break
            x = self._onto(quantity, x + step, target, jac)
        return best, best_ratio, jac

    def _stale_columns(self, quantity: Quantity, x: np.ndarray, jac: np.ndarray) -> list[int]:
        """The coordinates a re-fit at ``x`` moves (not ``q`` alone) whose column of ``jac``
        the curves do not see: its norm under ``NULL_SINGULAR`` of the largest column's."""
        norms = np.linalg.norm(jac, axis=0)
        gradient = np.abs(self._gradient(quantity, x))
        moved = gradient < 0.999 * float(np.linalg.norm(gradient))
        stale = norms < NULL_SINGULAR * max(float(norms.max(initial=0.0)), 1e-300)
        return [int(j) for j in np.flatnonzero(stale & moved)]

    def _onto(
        self, quantity: Quantity, x: np.ndarray, target: float, jac: np.ndarray
    ) -> np.ndarray:
        """``x`` moved onto ``q = target`` (Newton's steps on algebra, no runs), within the
        box: along the direction that moves ``q`` at the least misfit by the Gauss–Newton
        model (:func:`_linear_shift`), ``∂q/∂x`` where it has none. Along the raw gradient
        alone, Ecoat held at a thin stiff coat's value moved log D too (the misfit rose
        10⁵-fold where the valley of equally good coats fitted). Where that leaves ``q``
        short of ``target``, Newton's steps along ``∂q/∂x`` follow: the Gauss–Newton model
        can send ``q`` along a coordinate a range holds (log D below where Ecoat's lower
        bound holds it: its column zero in a Jacobian from a held point), where ``q``
        stays put (seen: D's lower side of a coat held at Ecoat's bound re-fitted at the
        optimum's D eight times, and was stated open)."""
        for raw in (False, True):
            for _ in range(ONTO_STEPS):
                gap = target - quantity.scaled(self.model.point(x))
                gradient = self._gradient(quantity, x)
                if abs(gap) < 1e-12 or not np.any(gradient):
                    return x
                direction = gradient / float(gradient @ gradient)
                if not raw:
                    shift = _linear_shift(jac, gradient, 1.0, capped=False)
                    direction = shift if float(gradient @ shift) > 0.0 else direction
                moved = np.clip(x + gap * direction, 0.0, 1.0)
                if np.array_equal(moved, x):
                    break
                x = moved
            span = abs(float(np.diff(quantity.range_scaled)[0]))
            if abs(target - quantity.scaled(self.model.point(x))) <= ONTO_TOLERANCE * span:
                break
        return x

    def _gradient(self, quantity: Quantity, x: np.ndarray) -> np.ndarray:
        return quantity_gradient(self.model, quantity, x)


def end_value(quantity: Quantity, q0: float, sign: float, size: float) -> float | None:
    """The quantity at ``|η| = size`` from ``q0`` (declared scale) on the side ``sign``; None
    within ``OPEN_UNIT`` of its range's end: the ranges, not the curves, end it there."""
    end = quantity.range_scaled[1 if sign > 0 else 0]
    span = abs(np.diff(quantity.range_scaled)[0])
    if abs(end - (q0 + sign * size)) <= OPEN_UNIT * span:
        return None
    return quantity.unscaled(q0 + sign * size)


def quantity_gradient(model: Any, quantity: Quantity, x: np.ndarray) -> np.ndarray:
    """``∂q/∂x`` at fit coordinates ``x`` of ``model`` (a :class:`~._local.ResidualModel`)
    by central differences of algebra (no runs)."""
    gradient = np.empty(x.size)
    for j in range(x.size):
        step = np.zeros(x.size)
        step[j] = FD_STEP_Q
        up = model.point(np.clip(x + step, 0.0, 1.0))
        down = model.point(np.clip(x - step, 0.0, 1.0))
        gradient[j] = (quantity.scaled(up) - quantity.scaled(down)) / (2 * FD_STEP_Q)
    return gradient


def _ranged(
    quantity: Quantity, sign: float, under: _Step, over: _Step, earlier: Sequence[_Step] = ()
) -> bool:
    """Whether the ranges, not the curves, end a side: the misfit flat along a stretch of
    the side (:func:`_flat`, :func:`_stretch`) up to a step over the threshold that a range
    holds — never on a side the curves see at every coat (``ALWAYS_SEEN``). A flat optimum
    and a held first step are no such stretch: cover-037's plastic moment, ρ 7·10⁵ at −19 %
    with Scoat at its bound, had been stated free in its range; nor a rise the curves make:
    the plastic moment of a coat a 5 mm test barely yields, ρ 0.22 at −5.1 % and 12.9 at
    −5.6 % (a range holding both), is bounded by the curves."""
    return _range_holds(quantity, sign, under, over) and _flat(under, earlier)


def _always_seen(quantity: Quantity, sign: float) -> bool:
    """Whether the curves see this side of ``quantity`` at every coat (``ALWAYS_SEEN``)."""
    return (quantity.name, sign) in ALWAYS_SEEN


def _range_holds(quantity: Quantity, sign: float, under: _Step, over: _Step) -> bool:
    """Whether a range holds the step ``over`` beyond a stretch of re-fits under the
    threshold, on a side the curves do not see at every coat: what :func:`_ranged` asks
    before the misfit's flatness."""
    if _always_seen(quantity, sign) or not over.held:
        return False
    return _stretch(under, over)


def _stretch(under: _Step, beyond: _Step) -> bool:
    """Whether the re-fits under the threshold reach at least as far out as the step
    ``beyond`` lies past them: a flat optimum alone is no stretch."""
    return under.size > 0.0 and under.size >= beyond.size - under.size


def _leap(found: _Step, under: _Step, earlier: Sequence[_Step]) -> bool:
    """Whether ``found`` leaps far over the threshold (ρ > ``FAR_OVER``) where no range holds
    it, beyond a flat stretch of the side's own re-fits: a re-fit that cannot follow a trade
    of parameters (cover-005's k_s: ρ 523 at −0.049, ρ 0.18 at every step up to −0.043; the
    truth, −0.055, fits at 0.59; a fresh Jacobian brought it no lower) — the side is not
    checked beyond it. Judged on a parameter's sides and Mp's upper one, not where the curves
    see the side at every coat (``ALWAYS_SEEN``: D's, and Mp's lower, where a leap is the
    physics: a plastic moment low enough to yield within the test, where none did). A higher
    Mp only delays a yield: seen, a coat with no plateau at 10 mm (0.6/0.35/0.02, noise seed
    502) fitted with Tcoat at its lower bound, Mp's re-fits at ρ 0.00 out to +0.43 in log Mp
    and 5,684 at +0.52, "Mp 4.29–7.55" stated where the truth, 8.26, fits as well."""
    return (
        _far_unheld(found)
        and any(e is under for e in earlier)  # the side's own: not a point found elsewhere
        and _stretch(under, found)
        and _flat(under, earlier)
    )


def _far_unheld(step: _Step) -> bool:
    """Whether a re-fit lies far over the threshold (ρ > ``FAR_OVER``) with no range holding
    it: one that could not follow a trade of parameters, beyond a flat stretch (:func:`_leap`)."""
    return step.ratio > FAR_OVER and not step.held


def _flat(under: _Step, earlier: Sequence[_Step]) -> bool:
    """Whether the misfit is flat along a side up to ``under``: ``ρ`` there under
    ``RANGED``, or under the threshold and risen no more than ``FLAT_RISE`` times from an
    ``earlier`` re-fit of the side at half the distance or less (a quadratic rise gives 4 ×;
    seen: ρ 0.763, 0.759, 0.759, 0.759 at +4.7, +9.9, +21 and +46 % in Mp, a coat a 5 mm
    test barely yields, then 4.6·10⁴ where Ecoat reached its bound) — or from one nearer,
    at least ``1/FLAT_NEAREST`` of the way in, by no more than the same power of the
    distances' ratio (``FLAT_RISE`` = 2^0.32; cover-089 of 240: k_s's re-fits at ρ 0.7099
    at −0.112, −0.135 and −0.137, none at half the way; cover-218: Tcoat's at 0.54 and 0.46
    at −1.10 and −1.45 in log Tcoat, then 4.9·10⁴ where a range held it). Beyond such a
    stretch, a step over the threshold that a range holds is the range's wall
    (:func:`_ranged`), and a parameter's leap far over it where none does is a re-fit that
    cannot follow the trade of parameters (:func:`_leap`)."""
    if under.ratio < RANGED:
        return True
    power = math.log(FLAT_RISE) / math.log(2.0)  # (FLAT_RISE at half the way: 2^power)
    return under.ratio < AGREES[0] and any(
        0.0 < e.ratio
        and e.size * FLAT_NEAREST <= under.size
        and under.ratio <= e.ratio * min(under.size / e.size, 2.0) ** power
        for e in earlier
    )


def _pinned(unit: np.ndarray) -> np.ndarray:
    """Where a point (declared unit coordinates) lies within ``PIN_UNIT`` of a bound."""
    return (unit <= PIN_UNIT) | (unit >= 1.0 - PIN_UNIT)


def _linear_shift(
    jac: np.ndarray, gradient: np.ndarray, eta: float, *, capped: bool = True
) -> np.ndarray:
    """The Gauss–Newton model's constrained minimum: the step ``δ`` with ``g·δ = η`` that
    least raises ``‖r + J δ‖`` — along the directions ``J`` does not see at all where
    ``g`` has a share ``UNSEEN_SHARE`` of them (it costs nothing there), else
    ``η C g / gᵀCg`` with ``C = (JᵀJ)⁻¹`` from the singular values of ``J`` (not of
    ``JᵀJ``: a valley of equally good coats makes it too ill-conditioned to square); no
    coordinate moved farther than ``TRUST`` (a sliver of an unseen direction in ``g``
    made it leap along the valley; ``capped`` False: the step as the model has it)."""
    _, singular, vt = np.linalg.svd(jac, full_matrices=False)
    seen = singular > NULL_SINGULAR * max(float(singular.max(initial=0.0)), 1e-300)
    basis = vt[seen]
    unseen = gradient - basis.T @ (basis @ gradient)
    if float(unseen @ unseen) >= UNSEEN_SHARE * float(gradient @ gradient):
        shift = eta * unseen / float(gradient @ unseen)
    else:
        solved = basis.T @ ((basis @ gradient) / singular[seen] ** 2)
        along = float(gradient @ solved)
        shift = eta * solved / along if along > 0.0 else np.zeros_like(gradient)
    if not capped:
        return shift
    largest = float(np.max(np.abs(shift), initial=0.0))
    return shift * (TRUST / largest) if largest > TRUST else shift


def _tangent_step(
    residual: np.ndarray,
    jac: np.ndarray,
    gradient: np.ndarray,
    x: np.ndarray,
    lifted: np.ndarray | None = None,
) -> np.ndarray:
    """The Gauss–Newton step ``d`` that minimises ``‖r + J d‖`` with ``g·d = 0`` (a heavy
    row), damped (Levenberg–Marquardt, ``DAMPING`` of ``‖J‖²``: along directions the
    curves hardly see, the undamped step leapt to its bounds, and off the valley), within
    the box and ``±TRUST`` of ``x`` (``±TRUST`` alone along the coordinates ``lifted``)."""
    scale = max(float(np.linalg.norm(jac)), 1e-12)
    weight = 1e3 * scale / max(float(np.linalg.norm(gradient)), 1e-300)
    damping = math.sqrt(DAMPING) * scale * np.eye(x.size)
    matrix = np.vstack([jac, weight * gradient, damping])
    target = np.concatenate([-residual, [0.0], np.zeros(x.size)])
    low = np.maximum(-x, -TRUST)
    high = np.maximum(np.minimum(1.0 - x, TRUST), low + 1e-15)
    if lifted is not None:
        low, high = np.where(lifted, -TRUST, low), np.where(lifted, TRUST, high)
    return lsq_linear(matrix, target, bounds=(low, high), method="bvls").x


# the moduli a coat's section and Tcoat determine: (modulus, section, per-GPa function's name)
PROJECTED = (
    ("ecoat_gpa", "bending_stiffness_nmm", "d_per_gpa"),
    ("scoat_gpa", "plastic_moment_n", "m_per_gpa"),
)


PROJECTED_MODULI = tuple(modulus for modulus, _, _ in PROJECTED)
SECTIONS = tuple(section for _, section, _ in PROJECTED)


def projected(
    quantity: Quantity,
    value: float,
    section: Profile,
    tcoat: Profile,
    per_gpa: Callable[[float], float],
    tcoat_spec: ParameterSpec,
) -> Profile:
    """Ecoat's (Scoat's) interval from the profiles of D (Mp) and Tcoat: the modulus is
    ``section / per_gpa(Tcoat)`` (the coat's section, exactly), rising with the section and
    falling with Tcoat, so over the box of the two intervals its least value lies at the
    section's lower end and Tcoat's upper one, its largest at the other two. The 95 %
    region lies inside that box, so the interval holds every coat the region holds — no
    narrower than the modulus's own profile, and no run (the two profiles were a third of
    every calibration's profile runs, 2,620 of 8,772 on 80 coverage sets).

    A side is open where the section's side is, where it reaches the modulus's range, or
    where Tcoat's side is open because the misfit was flat up to Tcoat's range (the ranges,
    not the curves, end it there) — not where the optimum's Tcoat is at that end already:
    there the box's corner at Tcoat's bound is the end, as a walk would find it. Its
    ``point`` and ``ratio`` are Tcoat's side's where it is open because that side is (the
    coat at that end of the valley of equally good coats: what a next test would separate),
    else None: a closed end here is no re-fit of its own, to verify or to separate.
    ``unchecked`` where a side it comes from is."""
    unit = float(tcoat_spec.to_unit(np.array([tcoat.value]))[0])
    sides = []
    for lower in (True, False):
        section_side = section.lower if lower else section.upper
        tcoat_side = tcoat.upper if lower else tcoat.lower
        bound = tcoat_spec.high if lower else tcoat_spec.low  # Tcoat's range end on that side
        at_bound = bool(_pinned(np.array([unit]))[0]) and (unit > 0.5) == lower
        end: float | None = None
        opened_by_tcoat = tcoat_side.end is None and not at_bound
        if section_side.end is not None and not opened_by_tcoat:
            thickness = bound if tcoat_side.end is None else tcoat_side.end
            q0 = quantity.scale(value)
            reach = quantity.scale(section_side.end / per_gpa(thickness)) - q0
            size = max(-reach if lower else reach, 0.0)
            far = abs(quantity.range_scaled[0 if lower else 1] - q0)  # to the range's end
            end = end_value(quantity, q0, -1.0 if lower else 1.0, min(size, far))
        methods = {section_side.method, tcoat_side.method}
        method = "unchecked" if "unchecked" in methods else "profile"
        if opened_by_tcoat:
            sides.append(ProfileSide(None, method, tcoat_side.ratio, 0, tcoat_side.point))
        else:
            sides.append(ProfileSide(end, method, None, 0, None))
    return Profile(quantity.name, value, sides[0], sides[1])


def profile(
    model: ResidualModel,
    fit: LocalFit,
    quantities: Sequence[tuple[Quantity, Any]],
    *,
    known: Sequence[np.ndarray] = (),
) -> tuple[list[Profile], np.ndarray | None]:
    """Profiles of ``quantities`` (each with its linear interval's ends) about ``fit``, and
    a point below the optimum where one was found (another basin), else None. ``known``:
    parameter points whose runs are done (verified points), in the region where under
    the threshold. Ecoat and Scoat, where D, Mp and Tcoat are profiled, are
    :func:`projected` from those, with no run.

    Every point found under the threshold is in the 95 % region: a side whose end a later
    profile's point lies beyond is profiled again from there (:meth:`Profiler.revisited`).
    Where the fit holds Ecoat or Scoat at its bound, D and Mp are profiled with that modulus
    in its own coordinate (:meth:`~._local.ResidualModel.declaring`): in the fit coordinates
    a held modulus is a kink — below it the section follows Tcoat alone — and a re-fit's
    Gauss–Newton step across it moved D where it meant to move Mp (0.6/0.35/0.02 GPa/GPa/mm
    at 10 mm, fitted with Ecoat held: "Mp 4.29–5.65" stated, the truth 8.26 and the straight
    path to it under 0.44 of the threshold). Tcoat keeps the fit coordinates, in which the
    valley is straight (in the declared ones, a Scoat held at its bound made Tcoat's re-fits
    crawl: cover-227 of 240 stated Tcoat to ±0.4 % with the truth 24 % off). The two
    profilers know each other's points."""
    profiler = Profiler(model, fit)
    profiler.know(known)
    space = model.problem.space
    unit = np.clip(space.to_unit(np.asarray(fit.theta, dtype=float)[None, :])[0], 0.0, 1.0)
    held = frozenset(
        name
        for name in PROJECTED_MODULI
        if name in space.names and _pinned(unit)[space.names.index(name)]
    )
    sections = profiler
    if held:
        declared = model.declaring(held)
        try:  # the optimum's Jacobian in those coordinates: a run a condition group each,
            declared.check_jacobian_fits(unit)  # none begun where the budget cannot finish it
            sections = Profiler(declared, fit)  # (known: :func:`_share`)
        except BudgetSpent:  # …that the budget refuses: the fit coordinates' kink stays
            pass
    names = {quantity.name for quantity, _ in quantities}
    coordinates = model.coordinates
    derived = {
        modulus: (section, getattr(coordinates, function))
        for modulus, section, function in PROJECTED
        if coordinates.coating and {modulus, section, "tcoat_mm"} <= names
    }
    found: dict[str, Profile] = {}
    profiled = [(q, linear) for q, linear in quantities if q.name not in derived]
    owner = {q.name: sections if q.name in SECTIONS else profiler for q, _ in profiled}
    for quantity, linear in profiled:
        _share(profiler, sections)
        found[quantity.name] = owner[quantity.name].profile(quantity, linear)
    _share(profiler, sections)
    for quantity, _ in profiled:  # an end a later profile's point contradicts: again
        found[quantity.name] = owner[quantity.name].revisited(quantity, found[quantity.name])
    theta = model.point(profiler.optimum.x)
    for quantity, _ in quantities:
        if quantity.name in derived:
            section, per_gpa = derived[quantity.name]
            found[quantity.name] = projected(
                quantity,
                quantity.value(theta),
                found[section],
                found["tcoat_mm"],
                per_gpa,
                coordinates.t,
            )
    better = profiler.better if sections.better is None else sections.better
    return [found[quantity.name] for quantity, _ in quantities], better


def _share(first: Profiler, second: Profiler) -> None:
    """Each profiler told the points the other found under the threshold since the last
    time (no runs: the result cache holds them)."""
    if first is second:
        return
    news = [
        [seen.point(one) for seen in one.seen[one.shared :] if seen.ratio < AGREES[0]]
        for one in (first, second)
    ]
    second.know(news[0])
    first.know(news[1])
    first.shared, second.shared = len(first.seen), len(second.seen)
