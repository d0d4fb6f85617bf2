"""The main job's model when the full solver is external: the built-in solver, corrected.

The scheme's rules are :mod:`surrogate.solvers._fidelity`'s. Here:

- :class:`LowFidelity` runs the built-in counterpart of points of the study (the same
  rig through the one model-state path), memoised by input hash and counted — the
  runs the search spends instead of expensive ones;
- :class:`CorrectedModel`: the built-in F60 and θsat corrected by two discrepancies
  learned from the expensive runs so far, ``log F60 = log F60_builtin + δ_F`` and
  ``θsat = θsat_builtin + δ_θ`` (:class:`surrogate.gp.Discrepancy`, on the model state's
  features) — with the ``predict(X, return_std)`` the loop's search reads from a
  surrogate, so the same constrained Optuna search and the same choice of candidates
  run on it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..gp import Discrepancy
from ..solvers._batch import solve_inputs
from ..solvers._cache import input_hash
from ..solvers._fidelity import (
    Correction,
    correction_refused,
    discrepancy_inputs,
    low_fidelity_inputs,
    too_rough,
)
from ..study._spec import StudySpec
from ._verify import Verification, verification_inputs

__all__ = ["CorrectedModel", "LowFidelity"]

F60_PRIOR_SD = 0.05  # log F60: before any expensive run the solvers may differ by ~5 %
F60_NOISE_SD = 1e-3  # the expensive F60's own scatter (mesh, increments): ~0.1 %
THETA_PRIOR_SD_DEG = 5.0  # θsat: they may differ by ~5° (CalculiX's yield spreads later)
THETA_NOISE_SD_DEG = 1.0 / np.sqrt(12.0)  # θsat's 1° grid
SENSITIVITY_STEP = 0.05  # +5 % of each parameter, as the full-solver sensitivities


class LowFidelity:
    """The built-in counterparts of the study's runs, memoised; ``runs`` counts them."""

    def __init__(self, spec: StudySpec) -> None:
        self.spec = spec
        self.runs = 0
        self._memo: dict[str, dict[str, Any]] = {}

    def result(self, params: Mapping[str, float]) -> dict[str, Any]:
        """The built-in run of the study's run at ``params`` (a failure is a result)."""
        inputs = low_fidelity_inputs(verification_inputs(self.spec, params))
        key = input_hash(inputs)
        if key not in self._memo:
            self._memo[key] = solve_inputs(inputs)
            self.runs += 1
        return self._memo[key]

    def results(self, X: np.ndarray) -> list[dict[str, Any]]:
        names = self.spec.space.names
        return [self.result(dict(zip(names, map(float, x), strict=True))) for x in X]


def _expensive_result(record: Verification) -> dict[str, Any]:
    return {
        "angle_deg": record.angle_deg,
        "force_n": record.force_n,
        "f60_n": record.f60_n,
        "theta_sat_deg": record.theta_sat_deg,
    }


class CorrectedModel:
    """The built-in F60 and θsat corrected towards the expensive solver.

    Parameters
    ----------
    spec : StudySpec
        The study (its rig and solver settings name the runs).
    low : LowFidelity
        The built-in runs.
    records : sequence of Verification
        The expensive runs so far; the successful ones whose built-in counterpart ran
        teach the discrepancies.
    """

    def __init__(self, spec: StudySpec, low: LowFidelity, records: Sequence[Verification]) -> None:
        self.spec, self.low = spec, low
        self.pairs = [(r, low.result(r.params)) for r in records if r.ok]
        self.pairs = [(r, lo) for r, lo in self.pairs if lo["status"] == "ok"]
        self.f60 = Discrepancy(F60_PRIOR_SD, noise_sd=F60_NOISE_SD)
        self.theta = Discrepancy(THETA_PRIOR_SD_DEG, noise_sd=THETA_NOISE_SD_DEG)
        if self.pairs:
            Z = np.array([self._inputs(r.params) for r, _ in self.pairs])
            self.f60.fit(Z, [np.log(r.f60_n / lo["f60_n"]) for r, lo in self.pairs])
            self.theta.fit(Z, [r.theta_sat_deg - lo["theta_sat_deg"] for r, lo in self.pairs])

    def _inputs(self, params: Mapping[str, float]) -> np.ndarray:
        return discrepancy_inputs(verification_inputs(self.spec, params))

    def predict(self, X: np.ndarray, return_std: bool = False) -> dict[str, np.ndarray]:
        """``{"f60_n", "theta_sat_deg"}`` (and ``f60_n_std``, ``log_f60_std``,
        ``theta_sat_deg_std``) at ``X`` (n, d); NaN where the built-in solver failed."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        names = self.spec.space.names
        lows = self.low.results(X)
        f60_lo = np.array([lo["f60_n"] if lo["status"] == "ok" else np.nan for lo in lows])
        theta_lo = np.array(
            [lo["theta_sat_deg"] if lo["status"] == "ok" else np.nan for lo in lows]
        )
        Z = np.array([self._inputs(dict(zip(names, x, strict=True))) for x in X])
        mu_f, sd_f = self.f60.predict(Z, return_std=True)
        mu_t, sd_t = self.theta.predict(Z, return_std=True)
        f60 = f60_lo * np.exp(mu_f[:, 0])
        out = {
            "f60_n": f60,
            "theta_sat_deg": np.clip(theta_lo + mu_t[:, 0], 0.0, self.spec.rig.max_angle_deg),
        }
        if return_std:
            out["f60_n_std"] = f60 * sd_f[:, 0]
            out["log_f60_std"] = sd_f[:, 0]
            out["theta_sat_deg_std"] = sd_t[:, 0]
        return out

    def refused(self) -> str | None:
        """Why the correction is not trusted at the runs so far, or None: its size at any
        run, or (once its GP chose its nugget) an F60 scatter beyond half the tolerance."""
        for record, low in self.pairs:
            reason = correction_refused(Correction.between(low, _expensive_result(record)))
            if reason is not None:
                return reason
        if self.f60.selected:
            tolerance = float(np.log1p(self.spec.targets.tolerance))
            return too_rough(float(self.f60.scatter[0]), tolerance, what="in log F60")
        return None

    def correction(self, record: Verification) -> Correction | None:
        """The size of the correction at an expensive run (None if the built-in failed)."""
        low = self.low.result(record.params)
        if low["status"] != "ok" or not record.ok:
            return None
        return Correction.between(low, _expensive_result(record))

    def sensitivities(self, record: Verification) -> np.ndarray | None:
        """``∂ log F60 / ∂ log p`` of the corrected model at a verified point: forward
        differences of ``SENSITIVITY_STEP`` (inwards at an upper bound), built-in runs
        corrected by ``δ_F``; None where the built-in solver fails."""
        names = self.spec.space.names
        point = np.array([record.params[n] for n in names])
        step = np.log1p(SENSITIVITY_STEP)
        directions = np.array(
            [
                1.0 if point[k] * (1 + SENSITIVITY_STEP) <= self.spec.space[n].high else -1.0
                for k, n in enumerate(names)
            ]
        )
        shifted = point * np.exp(np.diag(directions * step))
        values = np.log(self.predict(np.vstack([point, shifted]))["f60_n"])
        if not np.all(np.isfinite(values)):
            return None
        return directions * (values[1:] - values[0]) / step
