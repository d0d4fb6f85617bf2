"""``run``: the main job — constrained Optuna search on the surrogate, verified by
the full solver, until a verified point meets the target.

Optuna lives at this edge: full-solver runs are trials of the study
``<name>/verify`` in the study's storage (params, the misfit as value, the
constraint values, F60, θsat and the curve); the search on the surrogate is an
in-memory Optuna study per iteration.
"""

from __future__ import annotations

import contextlib
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
from .._pool import one_blas_thread_within
from .._validate import check_budget, check_seed
from ..solvers._fidelity import MissCounter, fidelity_record
from ..storage._optuna import distributions
from ..storage._storage import (
    STORAGE_PATIENCE_S,
    check_heartbeat,
    check_storage_patience,
    check_workers,
)
from ..study._spec import StudySpec, Targets, load_study
from ._commands import fit_surrogate
from ._doe import make_design
from ._fidelity import CorrectedModel, LowFidelity
from ._identifiability import assess_identifiability
from ._jobs import prepare_launch
from ._objective import constraint_values, is_feasible, refuse_model_effects, relative_misfit
from ._verify import Verification, Verifier, open_verify_study, target_of, verify_study_name
from ._worker import HEARTBEAT_S, WorkerDispatcher

__all__ = ["RunResult", "run"]

THETA_MARGIN_SIGMA = 1.645  # one-sided 95 % margin on the predicted θsat
_SEARCH_BATCH = 10
_LEAST_LIKELY = 1e-9  # a chance of meeting the target below this is none


@dataclass(frozen=True)
class RunResult:
    """Keys of ``surrogate run --json``.

    ``status`` is ``verified`` where a verified point meets the target; else
    ``budget_exhausted`` where the budget is what stopped the loop, or ``stalled`` where
    it stopped with runs left (the search proposed no point not verified already: a
    larger budget would not have been spent). ``verified`` is the chosen verified point
    (unverified statuses: the best verified point, which misses the target).
    ``solver_calls`` counts every full-solver run of the study, the
    identifiability runs after verification included; ``calls_to_verify``
    the runs until a verified point met the target.

    ``multi_fidelity`` (None for a built-in study): with an external full solver the
    built-in one is its prior (:mod:`surrogate.solvers._fidelity`) — ``low_fidelity``
    (``builtin``), ``low_fidelity_runs`` (built-in runs, counted apart from
    ``solver_calls``, which are the expensive ones), ``correction`` (the size of the
    correction at the answer, :class:`~surrogate.solvers._fidelity.Correction`),
    ``dropped`` (why the correction was not trusted and the single-fidelity loop took
    over, else None) and ``dropped_after`` (expensive runs by then). The identifiability
    exponents then come from the corrected model: no expensive runs after verification.

    ``study`` and ``storage`` name the Optuna study ``<name>/verify`` and its storage
    URL; ``identifiability`` is what the target determines (``statement``, the exponents
    of F60 in each parameter, the equally good points and whether they bear out the linear
    figure: :class:`~._identifiability.Identifiability`); ``iterations`` the search
    iterations; ``message`` the sentence the command prints.
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
    multi_fidelity: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@one_blas_thread_within
def run(
    study: str | Path | StudySpec,
    *,
    storage: str | None = None,
    seed: int | None = None,
    target: float | None = None,
    budget: int | None = None,
    jobs: int = 1,
    storage_patience_s: float = STORAGE_PATIENCE_S,
    progress: bool = True,
    launcher: str | None = None,
    heartbeat_s: int = HEARTBEAT_S,
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
    storage_patience_s : float
        With ``jobs != 1``, how long the planner keeps trying a database it reached
        before and cannot reach any more (a restart, a failover) — to queue runs, wait
        for them and write the result — before it stops (as a worker does).
    progress : bool
        Report each iteration (logger ``surrogate``, on stderr unless configured).
    launcher : str, optional
        ``slurm``: every verification is a job of the batch scheduler, one run a job
        (``[cluster]`` says what a job asks for; :mod:`surrogate.cluster`); ``jobs``
        must then be left at 1, and the storage one the cluster's nodes reach.
    heartbeat_s : int
        Heartbeat interval [s] of the workers (``jobs != 1``, ``launcher``); a run
        silent for three is retried.
    """
    spec = _with_overrides(study, seed=seed, target=target, budget=budget)
    storage_url = storage or spec.default_storage()
    check_workers(storage_url, jobs)
    check_storage_patience(storage_patience_s)
    check_heartbeat(heartbeat_s)
    if launcher is not None and jobs != 1:
        raise InputDataError(
            f"--jobs {jobs} with --launcher {launcher}: the scheduler's jobs run the "
            "verifications (at most [cluster] max_jobs at once); drop --jobs"
        )
    launch = prepare_launch(
        launcher,
        spec,
        storage_url,
        queue="verify",
        heartbeat_s=heartbeat_s,
        storage_patience_s=storage_patience_s,
    )
    jobs = 0 if launch is not None else jobs  # the planner solves nothing itself
    if progress:
        show_progress()
    verify_study = open_verify_study(
        spec, storage_url, heartbeat_s=None if jobs == 1 else heartbeat_s
    )
    dispatcher = None
    if jobs != 1:
        dispatcher = WorkerDispatcher(
            spec,
            storage_url,
            jobs=jobs,
            heartbeat_s=heartbeat_s,
            storage_patience_s=storage_patience_s,
            progress=progress,
        )
        if launch is not None:
            dispatcher.fleet = launch.fleet(
                verify_study,
                patience=dispatcher.patience,
                heartbeat_s=heartbeat_s,
                progress=progress,
            )
    verifier = Verifier(spec, verify_study, progress=progress, dispatch=dispatcher, replay=True)
    fidelity = _Fidelity(LowFidelity(spec)) if spec.low_fidelity else None
    fleet = dispatcher.fleet if dispatcher is not None else None
    with fleet if fleet is not None else contextlib.nullcontext():
        iterations = _search_and_verify(spec, verifier, fidelity)
    calls_to_verify = verifier.calls if verifier.chosen() is not None else None
    verifier.finish()
    return _result(spec, verifier, storage_url, iterations, calls_to_verify, fidelity)


def _search_and_verify(spec: StudySpec, verifier: Verifier, fidelity: _Fidelity | None) -> int:
    """The loop: an initial design, then surrogate → search → verification until a
    verified point meets the target or the budget is spent; returns the iterations.

    With an external full solver (``fidelity``) the corrected built-in model takes the
    surrogate's place from the first run on; where the correction is not trusted
    (:mod:`surrogate.solvers._fidelity`'s rules) this loop takes over, the expensive
    runs so far kept.
    """
    iteration, prefix = 0, ""
    if fidelity is not None:
        iteration = _corrected_search(spec, verifier, fidelity)
        if fidelity.dropped is None:
            return iteration
        prefix = "single fidelity: "
    # the same design whatever the budget (a resume with a larger one replays it); verify
    # runs what fits in the runs left (after a dropped correction, fewer than all)
    initial = make_design("lhs", spec.space, n=spec.budget.initial_samples, seed=spec.seed)
    verifier.verify(initial[list(spec.space.names)].to_numpy(), phase=f"{prefix}initial design")
    while verifier.chosen() is None and verifier.calls < spec.budget.max_solver_calls:
        iteration += 1
        model = fit_surrogate(verifier.sample_set(), seed=spec.seed, with_curves=False)
        candidates = _candidates(model, spec, verifier, iteration)
        if len(candidates) == 0:
            break
        verifier.verify(candidates, phase=f"{prefix}iteration {iteration}")
    return iteration


def _candidates(model: Any, spec: StudySpec, verifier: Verifier, iteration: int) -> np.ndarray:
    room = spec.budget.max_solver_calls - verifier.calls
    n = min(spec.budget.candidates_per_iteration, room)
    return _propose(model, spec, verifier.points(), iteration, n=n)


@dataclass
class _Fidelity:
    """The built-in solver as the prior of an external one: its runs, and why the
    correction was dropped (None while it is trusted)."""

    low: LowFidelity
    dropped: str | None = None
    dropped_after: int = 0


def _corrected_search(spec: StudySpec, verifier: Verifier, fidelity: _Fidelity) -> int:
    """Search the corrected built-in model and verify its candidates until a verified
    point meets the target; the first expensive run is the built-in model's own answer
    (its ``initial design``). Stops early, with ``fidelity.dropped`` set, where the
    correction is too large or too irregular — judged on batches that did not meet the
    target: a drop at the answer would start today's design on the expensive solver for
    nothing; returns the iterations."""
    misses = MissCounter()
    iteration = 0
    tolerance = float(np.log1p(spec.targets.tolerance))
    while verifier.chosen() is None and verifier.calls < spec.budget.max_solver_calls:
        model = CorrectedModel(spec, fidelity.low, list(verifier.records.values()))
        refused = model.refused()
        if refused is not None:
            fidelity.dropped, fidelity.dropped_after = refused, verifier.calls
            break
        candidates = _candidates(model, spec, verifier, iteration)
        if len(candidates) == 0:
            break
        predicted = model.predict(candidates, return_std=True)
        verifier.verify(
            candidates, phase="initial design" if iteration == 0 else f"iteration {iteration}"
        )
        iteration += 1
        if verifier.chosen() is not None:  # done: a batch that met the target drops nothing
            return iteration
        for i, point in enumerate(candidates):
            record = verifier.record(dict(zip(spec.space.names, map(float, point), strict=True)))
            if record is None or not record.ok or not np.isfinite(predicted["f60_n"][i]):
                continue
            error = float(np.log(record.f60_n / predicted["f60_n"][i]))
            if misses.judge(error, float(predicted["log_f60_std"][i]), tolerance):
                fidelity.dropped, fidelity.dropped_after = misses.reason, verifier.calls
                return iteration
    return iteration


# -- the study file and its overrides ----------------------------------------------------------
def _with_overrides(
    study: str | Path | StudySpec, *, seed: int | None, target: float | None, budget: int | None
) -> StudySpec:
    spec = study if isinstance(study, StudySpec) else load_study(study)
    if seed is not None:
        spec = dataclasses.replace(spec, seed=check_seed(seed))
    if target is not None:
        if not np.isfinite(target) or target <= 0:
            raise InputDataError(f"target f60_n must be a number > 0, got {target!r}")
        spec = dataclasses.replace(spec, targets=Targets(target, spec.targets.tolerance))
    if budget is not None:
        check_budget(budget)
        spec = dataclasses.replace(
            spec,
            budget=dataclasses.replace(spec.budget, max_solver_calls=budget),
        )
        spec.budget.check_main_job(spec.low_fidelity, "--budget")
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
        pred = _solved(model.predict(X, return_std=True))
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


def _solved(pred: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Predictions where a point the model could not evaluate (the corrected model's
    built-in run failed: NaN) is the worst there is: infinite misfit, θsat 0°, certain."""
    failed = ~np.isfinite(pred["f60_n"])
    if not failed.any():
        return pred
    out = dict(pred)
    out["f60_n"] = np.where(failed, np.inf, pred["f60_n"])
    for key in ("theta_sat_deg", "theta_sat_deg_std", "f60_n_std", "log_f60_std"):
        out[key] = np.where(failed, 0.0, pred[key])
    return out


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
    (probability within 80 % of the best found; where none has a chance above
    ``_LEAST_LIKELY``, the feasible point of least misfit), then the good points
    farthest from everything run so far.
    """
    trials = _search(model, spec, iteration)
    names = list(spec.space.names)
    unit_verified = spec.space.to_unit(verified) if len(verified) else np.empty((0, len(names)))
    unit_all = spec.space.to_unit(trials[names].to_numpy())
    fresh = np.array([_min_distance(u, unit_verified) > 1e-3 for u in unit_all])
    trials, unit_all = trials[fresh].reset_index(drop=True), unit_all[fresh]
    if trials.empty:
        return np.empty((0, len(names)))
    p_meet = trials.p_meet.to_numpy()
    if p_meet.max() > _LEAST_LIKELY:
        pool = np.flatnonzero(p_meet >= 0.8 * p_meet.max())
    else:  # a confident model sees no point within tolerance: the nearest feasible ones
        pool = np.array(
            [int(np.lexsort((trials.misfit.to_numpy(), ~trials.feasible.to_numpy()))[0])]
        )
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
    fidelity: _Fidelity | None,
) -> RunResult:
    chosen = verifier.chosen()
    if chosen is not None:
        status = "verified"
    elif verifier.calls >= spec.budget.max_solver_calls:
        status = "budget_exhausted"
    else:
        status = "stalled"
    point = chosen or verifier.best()
    verified = None
    identifiability: dict[str, Any] = {}
    if point is not None:
        verified = {
            **point.params,
            "f60_n": point.f60_n,
            "theta_sat_deg": point.theta_sat_deg,
        }
    model = _final_model(spec, verifier, fidelity)
    if point is not None and model is not None:
        good, verified_good = _equally_good(model, spec, verifier, iterations)
        if chosen is None and len(good) == 0:
            identifiability = {
                "statement": "No verified or predicted point meets the target, "
                "so the data determine nothing yet."
            }
        else:
            identifiability = _assess(
                spec, point, model, good, verified_good, chosen is not None, verifier
            )
    multi = _multi_fidelity(spec, fidelity, model, point)
    message = _message(spec, status, verifier, point, calls_to_verify)
    if multi is not None:
        message += multi.pop("sentence")
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
        multi,
    )
    verifier.publish(
        json.loads(json.dumps(result.to_json())),
        chosen_number=None if chosen is None else chosen.number,
        note=_note(spec, result),
    )
    return result


def _final_model(spec: StudySpec, verifier: Verifier, fidelity: _Fidelity | None) -> Any:
    """The model of every verified run, the last candidates included: the corrected
    built-in model while it is trusted, else the GP surrogate (None with < 3 runs)."""
    if fidelity is not None and fidelity.dropped is None:
        return CorrectedModel(spec, fidelity.low, list(verifier.records.values()))
    if sum(r.ok for r in verifier.records.values()) < 3:
        return None
    return fit_surrogate(verifier.sample_set(), seed=spec.seed, with_curves=False)


def _multi_fidelity(
    spec: StudySpec, fidelity: _Fidelity | None, model: Any, point: Verification | None
) -> dict[str, Any] | None:
    """The ``multi_fidelity`` record with its sentence (None for a built-in study)."""
    if fidelity is None:
        return None
    size = model.correction(point) if isinstance(model, CorrectedModel) and point else None
    return fidelity_record(
        spec.solver, fidelity.low.runs, size, fidelity.dropped, fidelity.dropped_after
    )


def _assess(
    spec: StudySpec,
    point: Verification,
    model: Any,
    good: np.ndarray,
    verified_good: int,
    verified: bool,
    verifier: Verifier,
) -> dict[str, Any]:
    """What the target determines around ``point``; the exponents at a verified point
    from the full solver (``identifiability_runs`` more runs) or, in a multi-fidelity
    study, from the corrected built-in model."""
    names = verifier.names
    gradient, source = None, None
    corrected = isinstance(model, CorrectedModel)
    if verified and corrected:
        gradient, source = model.sensitivities(point), "the corrected built-in model at the result"
    elif verified:
        gradient = verifier.sensitivities(point)
    assessment = assess_identifiability(
        names,
        np.array([point.params[n] for n in names]),
        lambda X: np.log(model.predict(X)["f60_n"]),
        good,
        tolerance=spec.targets.tolerance,
        preference_order=spec.preference_order,
        target_n=target_of(spec),
        solver_gradient=gradient,
        gradient_source=source,
        verified_good=verified_good,
        space=spec.space,
        predicted_by="the corrected built-in model" if corrected else "the surrogate",
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


def _equally_good(
    model: Any, spec: StudySpec, verifier: Verifier, iterations: int
) -> tuple[np.ndarray, int]:
    """The feasible points that meet the target: predicted by the search's surrogate,
    then the verified ones (their count)."""
    names = verifier.names
    trials = _search(model, spec, iterations + 1)
    predicted = trials[trials.feasible & (trials.misfit <= spec.targets.tolerance)]
    verified = [[r.params[n] for n in names] for r in verifier.meeting()]
    points = [predicted[names].to_numpy()]
    if verified:
        points.append(np.array(verified))
    return np.vstack(points), len(verified)


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
    ended = (
        f"budget exhausted after {verifier.calls} runs"
        if status == "budget_exhausted"
        else (
            f"stalled after {verifier.calls} of {spec.budget.max_solver_calls} runs: the "
            "search proposed no point not verified already, so a larger budget would not "
            "have been spent"
        )
    )
    if point is None:
        reasons = [r.reason for r in verifier.records.values() if r.reason]
        return (
            f"{ended} and no solver run succeeded"
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
        f"{ended}: no verified point meets the target {target:.4g} N "
        f"(± {100 * tolerance:g} %) with every constraint; "
        f"the best has F60 = {point.f60_n:.4g} N "
        f"(misfit {100 * point.misfit:.2f} %).{why}"
    )


def _reach(verifier: Verifier) -> tuple[float, float] | None:
    values = [r.f60_n for r in verifier.records.values() if r.ok]
    return (min(values), max(values)) if values else None
