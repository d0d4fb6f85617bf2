"""``run``: the main job — constrained Optuna search on the surrogate, verified by
the full solver, until a verified point meets the target.

Optuna lives at this edge: full-solver runs are trials of the study
``<name>/verify`` in the study's storage (params, the misfit as value, the
constraint values, F60, θsat and the curve); the search on the surrogate is an
in-memory Optuna study per iteration.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd
from scipy.stats import norm

from .._errors import InputDataError
from .._log import show_progress
from ..storage._dashboard import attach_run_report
from ..storage._optuna import distributions
from ..storage._storage import check_workers
from ..study._spec import StudySpec, Targets, load_study
from ._commands import fit_surrogate
from ._doe import make_design
from ._identifiability import assess_identifiability
from ._objective import constraint_values, is_feasible, refuse_model_effects, relative_misfit
from ._verify import Verification, Verifier, open_verify_study, target_of, verify_study_name
from ._worker import HEARTBEAT_S, WorkerDispatcher

__all__ = ["RunResult", "run"]

THETA_MARGIN_SIGMA = 1.645  # one-sided 95 % margin on the predicted θsat
_SEARCH_BATCH = 10


@dataclass(frozen=True)
class RunResult:
    """Keys of ``surrogate run --json``.

    ``verified`` is the chosen verified point (when ``status`` is
    ``budget_exhausted``: the best verified point, which misses the target).
    ``solver_calls`` counts every full-solver run of the study, the
    identifiability runs after verification included; ``calls_to_verify``
    the runs until a verified point met the target.
    """

    status: str
    solver_calls: int
    calls_to_verify: int | None
    verified: dict[str, float] | None
    study: str
    storage: str
    identifiability: dict[str, Any]
    iterations: int
    message: str

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def run(
    study: str | Path | StudySpec,
    *,
    storage: str | None = None,
    seed: int | None = None,
    target: float | None = None,
    budget: int | None = None,
    jobs: int = 1,
    progress: bool = True,
) -> RunResult:
    """Find coating parameters that meet the study's F60 target.

    Parameters
    ----------
    study : path or StudySpec
        The study file.
    storage : str, optional
        Optuna storage URL (default: ``sqlite:///`` file next to the study).
    seed, target, budget : optional
        Overrides of ``[study] seed``, ``[targets] f60_n`` and
        ``[budget] max_solver_calls``.
    jobs : int
        1: solve in this process. N > 1: N local worker processes verify each
        batch through the storage (not SQLite); 0: queue each batch and wait for
        ``surrogate worker`` processes elsewhere.
    progress : bool
        Report each iteration (logger ``surrogate``, on stderr unless configured).
    """
    spec = _with_overrides(study, seed=seed, target=target, budget=budget)
    storage_url = storage or spec.default_storage()
    check_workers(storage_url, jobs)
    if progress:
        show_progress()
    heartbeat_s = None if jobs == 1 else HEARTBEAT_S
    verifier = Verifier(
        spec,
        open_verify_study(spec, storage_url, heartbeat_s=heartbeat_s),
        progress=progress,
        dispatch=None
        if jobs == 1
        else WorkerDispatcher(spec, storage_url, jobs=jobs, progress=progress),
        replay=True,
    )
    iterations = _search_and_verify(spec, verifier)
    calls_to_verify = verifier.calls if verifier.chosen() is not None else None
    verifier.finish()
    return _result(spec, verifier, storage_url, iterations, calls_to_verify)


def _search_and_verify(spec: StudySpec, verifier: Verifier) -> int:
    """The loop: an initial design, then surrogate → search → verification until a
    verified point meets the target or the budget is spent; returns the iterations."""
    initial = make_design("lhs", spec.space, n=spec.budget.initial_samples, seed=spec.seed)
    verifier.verify(initial[list(spec.space.names)].to_numpy(), phase="initial design")
    iteration = 0
    while verifier.chosen() is None and verifier.calls < spec.budget.max_solver_calls:
        iteration += 1
        model = fit_surrogate(verifier.sample_set(), seed=spec.seed, with_curves=False)
        room = spec.budget.max_solver_calls - verifier.calls
        candidates = _propose(
            model,
            spec,
            verifier.points(),
            iteration,
            n=min(spec.budget.candidates_per_iteration, room),
        )
        if len(candidates) == 0:
            break
        verifier.verify(candidates, phase=f"iteration {iteration}")
    return iteration


# -- the study file and its overrides ----------------------------------------------------------
def _with_overrides(
    study: str | Path | StudySpec, *, seed: int | None, target: float | None, budget: int | None
) -> StudySpec:
    spec = study if isinstance(study, StudySpec) else load_study(study)
    if seed is not None:
        if seed < 0:
            raise InputDataError(f"--seed must be ≥ 0, got {seed}")
        spec = dataclasses.replace(spec, seed=seed)
    if target is not None:
        if not np.isfinite(target) or target <= 0:
            raise InputDataError(f"target f60_n must be a number > 0, got {target!r}")
        spec = dataclasses.replace(spec, targets=Targets(target, spec.targets.tolerance))
    if budget is not None:
        if budget < spec.budget.initial_samples:
            raise InputDataError(
                f"--budget must be ≥ budget.initial_samples "
                f"({spec.budget.initial_samples}), got {budget}"
            )
        spec = dataclasses.replace(
            spec,
            budget=dataclasses.replace(spec.budget, max_solver_calls=budget),
        )
    if spec.targets.f60_n is None:
        raise InputDataError(
            "surrogate run needs [targets] f60_n (or --target f60_n=VALUE); "
            "measured curves are calibrated with surrogate calibrate"
        )
    refuse_model_effects(spec, "surrogate run")
    return spec


# -- the search on the surrogate -------------------------------------------------------------
def _search(model: Any, spec: StudySpec, iteration: int) -> pd.DataFrame:
    """An in-memory Optuna study on the surrogate: constrained, cheap trials."""
    target, tolerance = target_of(spec), spec.targets.tolerance
    space = spec.space

    sampler = optuna.samplers.TPESampler(
        seed=spec.seed * 1000 + iteration,
        multivariate=True,
        n_startup_trials=min(40, spec.budget.surrogate_trials // 4),
    )
    search = optuna.create_study(direction="minimize", sampler=sampler)
    space_distributions = distributions(spec.space)
    rows: list[dict[str, Any]] = []
    while len(rows) < spec.budget.surrogate_trials:
        trials = [search.ask(space_distributions) for _ in range(_SEARCH_BATCH)]
        X = np.array([[t.params[n] for n in space.names] for t in trials])
        pred = model.predict(X, return_std=True)
        for i, trial in enumerate(trials):
            params = dict(zip(space.names, X[i], strict=True))
            misfit = relative_misfit(pred["f60_n"][i], target)
            constraints = constraint_values(
                params,
                pred["theta_sat_deg"][i],
                spec,
                theta_margin_deg=THETA_MARGIN_SIGMA * pred["theta_sat_deg_std"][i],
            )
            for name, value in constraints.items():
                trial.set_constraint(name, value)  # TPE samples the feasible region
            # Among points within tolerance, lean towards the preferred corner.
            lean = 0.25 * tolerance * _preference_score(params, spec)
            search.tell(trial, misfit + lean)
            rows.append(
                {
                    **params,
                    "misfit": misfit,
                    "feasible": is_feasible(constraints),
                    "p_meet": _probability_of_meeting(pred, i, spec),
                }
            )
    return pd.DataFrame(rows)


def _probability_of_meeting(pred: dict[str, np.ndarray], i: int, spec: StudySpec) -> float:
    """P(F60 within tolerance and θsat ≥ θmin) under the surrogate's predictive law."""
    half_width = np.log1p(spec.targets.tolerance)
    offset = np.log(pred["f60_n"][i] / target_of(spec))
    sd = max(float(pred["log_f60_std"][i]), 1e-12)
    p_f60 = norm.cdf((half_width - offset) / sd) - norm.cdf((-half_width - offset) / sd)
    theta_min = spec.constraints.theta_sat_deg_min
    if theta_min is None:
        return float(p_f60)
    theta_sd = max(float(pred["theta_sat_deg_std"][i]), 1e-12)
    # θsat lives on a 1° grid: half a degree below θmin still rounds to meeting it
    p_theta = norm.sf((theta_min - 0.5 - pred["theta_sat_deg"][i]) / theta_sd)
    return float(p_f60 * p_theta)


def _preference_score(params: dict[str, float], spec: StudySpec) -> float:
    """In [0, ~1.1]: the first preferred parameter counts fully, the next 1/10."""
    return sum(
        0.1**rank * float(spec.space[name].to_unit(np.array(params[name])))
        for rank, name in enumerate(spec.preference_order)
    )


def _propose(
    model: Any, spec: StudySpec, verified: np.ndarray, iteration: int, *, n: int
) -> np.ndarray:
    """Promising, diverse candidates.

    First the most preferred point among those most likely to meet the target
    (probability within 80 % of the best found), then the good points farthest
    from everything run so far.
    """
    trials = _search(model, spec, iteration)
    names = list(spec.space.names)
    unit_verified = spec.space.to_unit(verified) if len(verified) else np.empty((0, len(names)))
    unit_all = spec.space.to_unit(trials[names].to_numpy())
    fresh = np.array([_min_distance(u, unit_verified) > 1e-3 for u in unit_all])
    trials, unit_all = trials[fresh].reset_index(drop=True), unit_all[fresh]
    if trials.empty:
        return np.empty((0, len(names)))
    pool = np.flatnonzero(trials.p_meet.to_numpy() >= 0.8 * trials.p_meet.max())
    keys = [trials[name].to_numpy()[pool] for name in reversed(spec.preference_order)]
    chosen = [int(pool[np.lexsort(keys)[0]])]
    good = (trials.feasible & (trials.misfit <= 0.5 * spec.targets.tolerance)).to_numpy()
    while len(chosen) < n and good.sum() > len(chosen):
        taken = np.vstack([unit_verified, unit_all[chosen]])
        distances = np.array(
            [_min_distance(u, taken) if g else -1.0 for u, g in zip(unit_all, good, strict=True)]
        )
        distances[chosen] = -1.0
        chosen.append(int(np.argmax(distances)))
    return trials[names].to_numpy()[chosen]


def _min_distance(point: np.ndarray, others: np.ndarray) -> float:
    if len(others) == 0:
        return np.inf
    return float(np.min(np.linalg.norm(others - point, axis=1)))


# -- the result ------------------------------------------------------------------------------
def _result(
    spec: StudySpec,
    verifier: Verifier,
    storage_url: str,
    iterations: int,
    calls_to_verify: int | None,
) -> RunResult:
    chosen = verifier.chosen()
    status = "verified" if chosen is not None else "budget_exhausted"
    point = chosen or verifier.best()
    verified = None
    identifiability: dict[str, Any] = {}
    names = verifier.names
    if point is not None:
        verified = {
            **point.params,
            "f60_n": point.f60_n,
            "theta_sat_deg": point.theta_sat_deg,
        }
    n_ok = sum(r.ok for r in verifier.records.values())
    if point is not None and n_ok >= 3:
        # refit on every verified run, the last candidates included
        model = fit_surrogate(verifier.sample_set(), seed=spec.seed, with_curves=False)
        good = _equally_good(model, spec, verifier, iterations)
        if chosen is None and len(good) == 0:
            identifiability = {
                "statement": "No verified or predicted point meets the target, "
                "so the data determine nothing yet."
            }
        else:
            gradient = verifier.sensitivities(point) if chosen is not None else None
            identifiability = _assess(spec, names, point, model, good, gradient)
    message = _message(spec, status, verifier, point, calls_to_verify)
    result = RunResult(
        status,
        verifier.calls,
        calls_to_verify,
        verified,
        verify_study_name(spec),
        storage_url,
        identifiability,
        iterations,
        message,
    )
    # what `surrogate report` reads back: the result as the verify study's attribute
    verifier.study.set_user_attr("result", json.loads(json.dumps(result.to_json())))
    attach_run_report(
        verifier.study,
        target_n=target_of(spec),
        tolerance=spec.targets.tolerance,
        records=list(verifier.records.values()),
        chosen_number=None if chosen is None else chosen.number,
        note=_note(spec, result),
    )
    return result


def _assess(
    spec: StudySpec,
    names: list[str],
    point: Verification,
    model: Any,
    good: np.ndarray,
    gradient: np.ndarray | None,
) -> dict[str, Any]:
    assessment = assess_identifiability(
        names,
        np.array([point.params[n] for n in names]),
        lambda X: np.log(model.predict(X)["f60_n"]),
        good,
        tolerance=spec.targets.tolerance,
        preference_order=spec.preference_order,
        target_n=target_of(spec),
        solver_gradient=gradient,
    )
    return assessment.to_json()


def _note(spec: StudySpec, result: RunResult) -> str:
    lines = [f"## {spec.name}: {result.status}", "", result.message, ""]
    if result.verified:
        v = result.verified
        lines += [
            f"- Ecoat = {v['ecoat_gpa']:.4g} GPa",
            f"- Scoat = {v['scoat_gpa']:.4g} GPa",
            f"- Tcoat = {v['tcoat_mm']:.4g} mm",
            f"- F60 = {v['f60_n']:.4g} N, θsat = {v['theta_sat_deg']:g}°",
            "",
        ]
    if result.identifiability:
        lines += ["### Identifiability", "", result.identifiability["statement"]]
    return "\n".join(lines)


def _equally_good(model: Any, spec: StudySpec, verifier: Verifier, iterations: int) -> np.ndarray:
    names = verifier.names
    trials = _search(model, spec, iterations + 1)
    predicted = trials[trials.feasible & (trials.misfit <= spec.targets.tolerance)]
    verified = [[r.params[n] for n in names] for r in verifier.meeting()]
    points = [predicted[names].to_numpy()]
    if verified:
        points.append(np.array(verified))
    return np.vstack(points)


def _message(
    spec: StudySpec,
    status: str,
    verifier: Verifier,
    point: Verification | None,
    calls_to_verify: int | None,
) -> str:
    target, tolerance = target_of(spec), spec.targets.tolerance
    if status == "verified" and point is not None:
        return (
            f"verified: F60 = {point.f60_n:.4g} N is within {100 * tolerance:g} % of "
            f"the target {target:.4g} N and every constraint holds, after "
            f"{calls_to_verify} full-solver runs"
        )
    if point is None:
        reasons = [r.reason for r in verifier.records.values() if r.reason]
        return (
            f"budget exhausted after {verifier.calls} runs and no solver run succeeded"
            + (f" (the last: {reasons[-1]})" if reasons else "")
            + "; check the rig, the parameter ranges and the solver"
        )
    reach = _reach(verifier)
    why = ""
    if reach is not None and (target < reach[0] or target > reach[1]):
        why = (
            f" The verified runs give F60 between {reach[0]:.4g} and {reach[1]:.4g} N; "
            f"a target of {target:.4g} N is probably out of reach of the parameter ranges — "
            "widen them or check the target."
        )
    return (
        f"budget exhausted: no verified point meets the target {target:.4g} N "
        f"(± {100 * tolerance:g} %) with every constraint after {verifier.calls} runs; "
        f"the best has F60 = {point.f60_n:.4g} N "
        f"(misfit {100 * point.misfit:.2f} %).{why}"
    )


def _reach(verifier: Verifier) -> tuple[float, float] | None:
    values = [r.f60_n for r in verifier.records.values() if r.ok]
    return (min(values), max(values)) if values else None
