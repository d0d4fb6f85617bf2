"""The built-in solver as the low fidelity of an external full solver.

For a study whose full solver is external (CalculiX, LS-DYNA), the built-in rod of the
same test — same coating, rig, effects and conditions, through the one model-state
path — is a fast prior of the expensive response: ``expensive ≈ built-in ⊕ δ``, with the
discrepancy ``δ`` (:class:`surrogate.gp.Discrepancy`) learned from the expensive runs
(Kennedy & O'Hagan 2000, on a log scale). The main job and the calibration search the
corrected built-in model and ask the expensive solver only to verify a point or to teach
``δ``. One place for the scheme's rules:

- which studies use it (:func:`uses_low_fidelity`: an external solver, ``[solver]
  multi_fidelity`` not switched off) and the low-fidelity counterpart of a run
  (:func:`low_fidelity_inputs`);
- ``δ``'s inputs (:func:`discrepancy_inputs`: the model state's features over their
  spans, so ``δ`` learned on one model serves the model with an effect added); a curve's
  ``δ`` lives on the calibration surrogate's scale (:func:`surrogate.gp.latent_of_force`,
  logarithmic above a few hundredths of a newton);
- the size of the correction at a point (:class:`Correction`) and when the correction is
  not trusted: too large (:func:`correction_refused`), or too irregular — predictions
  missed twice in a row (:class:`MissCounter`), or, for the main job's scalar
  outputs, a scatter its GP calls noise beyond half the tolerance (:func:`too_rough`;
  not for whole curves: from a few points the nugget shared by ~90 correlated angles
  called CalculiX's discrepancy noise at the point that reached the noise floor);
- when a correction learned on another model (a diagnosis's confirmation inherits the
  current model's) does not carry to this one (:func:`not_carried`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..study import Rig
from ._base import get_solver
from ._batch import solver_inputs
from ._state import STATE_FEATURE_SPANS, model_state, state_features

__all__ = [
    "LOW_FIDELITY",
    "MAX_CORRECTION",
    "MISSES_IN_A_ROW",
    "MISS_SIGMAS",
    "ROUGH_SHARE",
    "Correction",
    "MissCounter",
    "correction_refused",
    "discrepancy_inputs",
    "fidelity_record",
    "low_fidelity_inputs",
    "not_carried",
    "too_rough",
    "uses_low_fidelity",
]

LOW_FIDELITY = "builtin"
MAX_CORRECTION = 0.25  # a correction beyond 25 % of the curve: the built-in is no model of it
MISS_SIGMAS = 3.0  # a prediction missed by more than this many of its standard deviations…
MISSES_IN_A_ROW = 2  # …twice in a row (and by more than the caller's tolerance): too irregular
ROUGH_SHARE = 0.5  # a discrepancy scattering by half the tolerance between runs: too irregular


def uses_low_fidelity(kind: str, multi_fidelity: bool) -> bool:
    """Whether a study's runs go through the corrected built-in model: an external
    solver (every kind but the built-in) with ``[solver] multi_fidelity`` on."""
    return multi_fidelity and kind != LOW_FIDELITY


def low_fidelity_inputs(inputs: Mapping[str, Any]) -> dict[str, Any]:
    """The same run (coating, rig, effects, conditions) on the built-in solver."""
    return solver_inputs(
        dict(inputs["params"]),
        Rig(**inputs["rig"]),
        solver=LOW_FIDELITY,
        effects=inputs.get("effects") or None,
        conditions=inputs.get("conditions") or None,
    )


def discrepancy_inputs(inputs: Mapping[str, Any]) -> np.ndarray:
    """``δ``'s inputs (k,) of a run: its model state's features in units of their spans."""
    return state_features(model_state(inputs)) / STATE_FEATURE_SPANS


def refusal(kind: str, state: Any) -> str | None:
    """Why solver ``kind`` cannot model ``state``, or None (:meth:`Solver.refuses`)."""
    return get_solver(kind).refuses(state)


@dataclass(frozen=True)
class Correction:
    """The size of the correction at a point: expensive against built-in.

    ``f60_percent`` ``100·(F60_exp/F60_builtin − 1)``; ``theta_sat_deg`` θsat_exp −
    θsat_builtin; ``curve_rmse_n`` the RMS difference of the two curves over whole
    degrees [N] and ``curve_rmse_relative`` that over the built-in curve's RMS (the worst
    condition group where there are several).
    """

    f60_percent: float
    theta_sat_deg: float
    curve_rmse_n: float
    curve_rmse_relative: float

    def to_json(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def between(cls, low: Mapping[str, Any] | Sequence[Mapping[str, Any]], high: Any) -> Correction:
        """From the plain-JSON results of the two solvers (lists: one per condition
        group; the group with the largest relative curve difference is reported)."""
        lows = [low] if isinstance(low, Mapping) else list(low)
        highs = high if isinstance(high, list) else [high]
        sizes = [_size(lo, hi) for lo, hi in zip(lows, highs, strict=True)]
        return max(sizes, key=lambda size: size.curve_rmse_relative)

    def describe(self, expensive: str) -> str:
        return (
            f"{expensive} against the built-in solver: F60 {self.f60_percent:+.2f} %, "
            f"θsat {self.theta_sat_deg:+.0f}°, curve RMSE {self.curve_rmse_n:.3g} N "
            f"({100 * self.curve_rmse_relative:.2g} %)"
        )


def _size(low: Mapping[str, Any], high: Mapping[str, Any]) -> Correction:
    angle = np.asarray(low["angle_deg"], dtype=float)
    lo = np.asarray(low["force_n"], dtype=float)
    hi = np.interp(angle, high["angle_deg"], high["force_n"])
    rmse = float(np.sqrt(np.mean((hi - lo) ** 2)))
    scale = float(np.sqrt(np.mean(lo**2)))
    return Correction(
        f60_percent=100.0 * (high["f60_n"] / low["f60_n"] - 1.0),
        theta_sat_deg=float(high["theta_sat_deg"] - low["theta_sat_deg"]),
        curve_rmse_n=rmse,
        curve_rmse_relative=rmse / scale if scale > 0 else float("inf"),
    )


def correction_refused(size: Correction) -> str | None:
    """Why a correction of this size is not trusted (None: it is): beyond
    ``MAX_CORRECTION`` of the curve the built-in solver is no model of the expensive one."""
    if size.curve_rmse_relative > MAX_CORRECTION:
        return (
            f"the expensive curve differs from the built-in one by "
            f"{100 * size.curve_rmse_relative:.0f} % of its RMS (F60 {size.f60_percent:+.1f} %), "
            f"more than the {100 * MAX_CORRECTION:.0f} % the correction is trusted for"
        )
    return None


def too_rough(scatter: float, tolerance: float, *, what: str) -> str | None:
    """The second irregularity rule: once the discrepancy's GP has chosen its length scale
    and nugget by likelihood, the scatter it attributes to noise (``scatter``, the same
    units as ``tolerance``) may not exceed ``ROUGH_SHARE`` of the tolerance — beyond, the
    corrected model cannot place a point within the tolerance."""
    if scatter > ROUGH_SHARE * tolerance:
        return (
            f"the discrepancy scatters by {scatter:.3g} {what} between expensive runs (its "
            f"GP's noise), more than {ROUGH_SHARE:g} of the tolerance {tolerance:.3g}: too "
            "irregular for its GP"
        )
    return None


def not_carried(error: float, sd: float, tolerance: float) -> str | None:
    """Why a correction learned on another model is not trusted to search this one (None:
    it is), judged at the corrected model's optimum — the first point the expensive
    solver verifies — by the prediction made there before the run: an ``error`` beyond
    the ``tolerance``, whatever its standard deviation ``sd`` said. Such a correction
    has not learned where this model's optimum lies, so the corrected model's optimum is
    a start, not a search result, and the expensive solver's own local phase goes on
    from the best verified point.

    Measured on CalculiX-made curves (README, "Multi-fidelity"): with hidden hardening
    the first point missed by 0.414 N (noise 0.047 N, 2.98 σ) and the corrected search
    went on into the built-in rod's basin, 5.9 × noise at the end; from that first
    point CalculiX's own local phase reached 1.07 ×. With hidden tension it missed by
    1.81 N (0.76 σ): 1.12 × the corrected way, 1.17 × this way. Not the standard
    deviation alone: where it was learned, a correction's standard deviation in newtons
    grows with the force (0.1 N at a model's own optimum, tests at 40 N, missed by
    0.003 N).
    """
    if abs(error) <= tolerance:
        return None
    return (
        f"at the corrected model's optimum the correction learned on the current model "
        f"missed by {abs(error):.3g} (its standard deviation {sd:.3g}, tolerance "
        f"{tolerance:.3g}): it has not learned where this model's optimum lies"
    )


class MissCounter:
    """The irregularity rule: an expensive run the corrected model predicted (before
    the run, from the runs so far) is a *miss* when its error exceeds ``MISS_SIGMAS``
    predicted standard deviations and the caller's tolerance; ``MISSES_IN_A_ROW``
    misses in a row mean ``δ`` is too irregular for its GP."""

    def __init__(self) -> None:
        self.in_a_row = 0
        self.last: str | None = None

    def judge(self, error: float, sd: float, tolerance: float) -> bool:
        """Record one prediction's ``error`` against its ``sd``; True when the rule now
        says the correction is too irregular."""
        miss = abs(error) > max(MISS_SIGMAS * sd, tolerance)
        self.in_a_row = self.in_a_row + 1 if miss else 0
        if miss:
            self.last = (
                f"an expensive run missed the corrected model's prediction by {abs(error):.3g} "
                f"({abs(error) / max(sd, 1e-300):.1f} standard deviations)"
            )
        return self.in_a_row >= MISSES_IN_A_ROW

    @property
    def reason(self) -> str:
        return (
            f"{MISSES_IN_A_ROW} expensive runs in a row missed the corrected model's "
            f"prediction by more than {MISS_SIGMAS:g} standard deviations and the tolerance "
            f"(the last: {self.last}): the discrepancy is too irregular for its GP"
        )


def fidelity_record(
    kind: str,
    low_fidelity_runs: int,
    correction: Correction | None,
    dropped: str | None,
    dropped_after: int,
    then: str = "the single-fidelity loop took over",
) -> dict[str, Any]:
    """The ``multi_fidelity`` key of ``run --json`` and ``calibrate --json``, and the
    sentence (``sentence``) their message ends with: the built-in runs spent and the size
    of the correction at the answer — or why the correction was dropped, and what went
    on (``then``)."""
    if dropped is not None:
        sentence = (
            f". The built-in solver was dropped as the prior after {dropped_after} {kind} "
            f"runs: {dropped}; {then}"
        )
    else:
        sentence = (
            f". Multi-fidelity: the searched model was the built-in solver corrected towards "
            f"{kind} ({low_fidelity_runs} built-in runs)"
        )
        if correction is not None:
            sentence += f"; at the answer {correction.describe(kind)}"
    return {
        "low_fidelity": LOW_FIDELITY,
        "low_fidelity_runs": low_fidelity_runs,
        "correction": None if correction is None else correction.to_json(),
        "dropped": dropped,
        "dropped_after": dropped_after if dropped is not None else None,
        "sentence": sentence,
    }
