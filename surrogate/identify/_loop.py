"""``run``: the main job — constrained Optuna search on the surrogate, verified by
the full solver, until a verified point meets the target.

Optuna lives at this edge: full-solver runs are trials of the study
``<name>/verify`` in the study's storage (params, the misfit as value, the
constraint values, F60, θsat and the curve); the search on the surrogate is an
in-memory Optuna study per iteration.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd
from scipy.stats import norm

from .._errors import InputDataError
from ..solvers._batch import solve_inputs, solver_inputs
from ..solvers._cache import ResultCache, input_hash
from ..storage._dashboard import attach_run_report
from ..storage._storage import check_workers
from ..study._samples import SampleSet
from ..study._spec import StudySpec, Targets, load_study
from ._commands import fit_surrogate
from ._doe import make_design
from ._identifiability import assess_identifiability
from ._objective import constraint_values, is_feasible, meets_target, relative_misfit

__all__ = ["RunResult", "run", "tell_verification", "verify_study_name"]

METRIC = "f60_relative_misfit"
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


def verify_study_name(spec: StudySpec) -> str:
    return f"{spec.name}/verify"


def _target_of(spec: StudySpec) -> float:
    target = spec.targets.f60_n
    assert target is not None  # checked by _with_overrides
    return target


def _distributions(spec: StudySpec) -> dict[str, optuna.distributions.BaseDistribution]:
    return {
        p.name: optuna.distributions.FloatDistribution(p.low, p.high, log=p.log) for p in spec.space
    }


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
        Report each iteration on stderr.
    """
    from ._worker import HEARTBEAT_S, WorkerDispatcher, open_planner_study

    spec = _with_overrides(study, seed=seed, target=target, budget=budget)
    storage_url = storage or spec.default_storage()
    check_workers(storage_url, jobs)
    _quiet_optuna()
    heartbeat_s = None if jobs == 1 else HEARTBEAT_S
    verifier = _Verifier(
        spec, open_planner_study(spec, storage_url, heartbeat_s=heartbeat_s), progress=progress
    )
    if jobs != 1:
        verifier.dispatch = WorkerDispatcher(spec, storage_url, jobs=jobs, progress=progress)
    initial = make_design("lhs", spec.space, n=spec.budget.initial_samples, seed=spec.seed)
    verifier.verify(initial[list(spec.space.names)].to_numpy(), phase="initial design")
    iteration, last_model = 0, None
    while verifier.chosen() is None and verifier.calls < spec.budget.max_solver_calls:
        iteration += 1
        last_model = fit_surrogate(verifier.sample_set(), seed=spec.seed)
        room = spec.budget.max_solver_calls - verifier.calls
        candidates = _propose(
            last_model,
            spec,
            verifier.points(),
            iteration,
            n=min(spec.budget.candidates_per_iteration, room),
        )
        if len(candidates) == 0:
            break
        verifier.verify(candidates, phase=f"iteration {iteration}")
    calls_to_verify = verifier.calls if verifier.chosen() is not None else None
    return _result(spec, verifier, storage_url, iteration, calls_to_verify)


# -- the verify study ------------------------------------------------------------------------
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
    return spec


def _quiet_optuna() -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    logging.getLogger("optuna").setLevel(logging.WARNING)
    # metric names are "experimental" since Optuna 3.2 and stable in use
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)


def _open_study(spec: StudySpec, storage_url: str) -> optuna.Study:
    study = optuna.create_study(
        storage=storage_url,
        study_name=verify_study_name(spec),
        direction="minimize",
        load_if_exists=True,
    )
    study.set_metric_names([METRIC])
    target = _target_of(spec)
    attrs = {
        "description": "full-solver verification runs of a coating identification "
        "(surrogate run); value = |F60/target - 1|, constraints <= 0 feasible",
        "objective": f"{METRIC} = |F60 / target - 1|",
        "target_f60_n": target,
        "tolerance": spec.targets.tolerance,
        "constraints": [
            "theta_sat_min: theta_min - theta_sat [deg]",
            "tcoat_max: Tcoat - fraction*t [mm]",
        ],
        "parameters": spec.space.to_dict(),
        "solver": spec.solver,
        "rig": spec.rig.to_dict(),
    }
    for key, value in attrs.items():
        if study.user_attrs.get(key) != value:
            study.set_user_attr(key, value)
    return study


class _Verifier:
    """Runs points with the full solver as trials of the verify study; resumes."""

    def __init__(self, spec: StudySpec, study: optuna.Study, *, progress: bool) -> None:
        self.spec = spec
        self.study = study
        self.progress = progress
        self.cache = ResultCache(spec.directory / ".solver-cache")
        self.names = list(spec.space.names)
        self.distributions = _distributions(spec)
        self.records: dict[str, dict[str, Any]] = {}
        # set by run(jobs != 1): verify batches through the storage's workers
        self.dispatch: Callable[[optuna.Study, list[dict[str, float]], str], dict] | None = None
        for trial in study.get_trials(
            deepcopy=False, states=(optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL)
        ):
            key = trial.user_attrs.get("input_hash")
            # a FAIL without a reason is an interrupted worker's run; its retry counts
            if key is not None and (trial.values or "reason" in trial.user_attrs):
                self.records[key] = _record_of(trial)

    @property
    def calls(self) -> int:
        return len(self.records)

    def points(self) -> np.ndarray:
        return np.array([[r["params"][n] for n in self.names] for r in self.records.values()])

    def verify(self, points: np.ndarray, *, phase: str) -> None:
        if self.dispatch is not None:
            room = self.spec.budget.max_solver_calls - self.calls
            batch = [
                dict(zip(self.names, map(float, p), strict=True)) for p in np.atleast_2d(points)
            ]
            self.records.update(self.dispatch(self.study, batch[: max(room, 0)], phase))
        for point in np.atleast_2d(points):
            if self.calls >= self.spec.budget.max_solver_calls:
                return
            self._solve(dict(zip(self.names, map(float, point), strict=True)), phase=phase)
        self._report(phase)

    def _tell(
        self, params: dict[str, float], key: str, result: dict[str, Any], phase: str
    ) -> dict[str, Any]:
        self.study.enqueue_trial(params, skip_if_exists=False)
        trial = self.study.ask(self.distributions)
        trial.set_user_attr("input_hash", key)
        trial.set_user_attr("phase", phase)
        return tell_verification(self.study, trial, self.spec, params, result)

    def sensitivities(self, point: dict[str, Any]) -> np.ndarray | None:
        """``∂ log F60 / ∂ log p`` at a verified point, by forward differences of
        the full solver (one run per parameter, +5 % each); None if the budget
        allows none (``[budget] identifiability_runs``)."""
        if self.spec.budget.identifiability_runs < len(self.names):
            return None
        step = np.log(1.05)
        gradient = np.empty(len(self.names))
        for k, name in enumerate(self.names):
            spec = self.spec.space[name]
            direction = 1.0 if point["params"][name] * 1.05 <= spec.high else -1.0
            shifted = {**point["params"], name: point["params"][name] * np.exp(direction * step)}
            record = self._solve(shifted, phase="identifiability")
            if record["status"] != "ok":
                return None
            gradient[k] = direction * np.log(record["f60_n"] / point["f60_n"]) / step
        return gradient

    def _solve(self, params: dict[str, float], *, phase: str) -> dict[str, Any]:
        """One full-solver run as a trial; a finished run is never repeated."""
        inputs = solver_inputs(
            params,
            self.spec.rig,
            solver=self.spec.solver,
            solver_settings=self.spec.solver_settings,
        )
        key = input_hash(inputs)
        if key not in self.records and self.dispatch is not None:
            self.records.update(self.dispatch(self.study, [params], phase))
        if key not in self.records:
            result = self.cache.get(key)
            if result is None:
                result = solve_inputs(inputs)
                self.cache.put(key, inputs, result)
            self.records[key] = self._tell(params, key, result, phase)
        return self.records[key]

    def meeting(self) -> list[dict[str, Any]]:
        tolerance = self.spec.targets.tolerance
        return [
            r
            for r in self.records.values()
            if r["status"] == "ok" and meets_target(r["misfit"], r["constraints"], tolerance)
        ]

    def chosen(self) -> dict[str, Any] | None:
        """The preferred verified point that meets the target, if any."""
        meeting = self.meeting()
        if not meeting:
            return None
        return min(meeting, key=lambda r: _preference_key(r["params"], self.spec))

    def best(self) -> dict[str, Any] | None:
        ok = [r for r in self.records.values() if r["status"] == "ok"]
        if not ok:
            return None
        return min(ok, key=lambda r: (not is_feasible(r["constraints"]), r["misfit"]))

    def sample_set(self) -> SampleSet:
        rows = [r for r in self.records.values() if r["status"] == "ok"]
        if len(rows) < 3:
            raise InputDataError(
                f"only {len(rows)} solver runs succeeded; the surrogate needs "
                "3 — check the parameter ranges"
            )
        runs = pd.DataFrame(
            {
                "run_id": np.arange(1, len(rows) + 1),
                **{n: [r["params"][n] for r in rows] for n in self.names},
                "f60_n": [r["f60_n"] for r in rows],
                "theta_sat_deg": [r["theta_sat_deg"] for r in rows],
                "status": "ok",
            }
        )
        curves = pd.concat(
            [
                pd.DataFrame(
                    {"run_id": i + 1, "angle_deg": r["angle_deg"], "force_n": r["force_n"]}
                )
                for i, r in enumerate(rows)
            ],
            ignore_index=True,
        )
        return SampleSet(runs, curves, self.spec.space, {})

    def _report(self, phase: str) -> None:
        if not self.progress:
            return
        best = self.best()
        text = (
            "no successful run yet"
            if best is None
            else (
                f"best verified misfit {100 * best['misfit']:.2f} %"
                + ("" if is_feasible(best["constraints"]) else " (infeasible)")
            )
        )
        met = " — target met" if self.chosen() is not None else ""
        print(
            f"[{self.spec.name}] {phase}: {self.calls}/{self.spec.budget.max_solver_calls} "
            f"solver calls, {text}{met}",
            file=sys.stderr,
            flush=True,
        )


def tell_verification(
    study: optuna.Study,
    trial: optuna.Trial,
    spec: StudySpec,
    params: dict[str, float],
    result: dict[str, Any],
) -> dict[str, Any]:
    """Finish ``trial`` with one full-solver ``result``; return the verifier's record.

    A failed run is a FAIL trial with its ``reason``; a successful one carries
    the misfit as value, the constraints (Optuna 5 and the list that
    optuna-dashboard 0.21 reads), F60, θsat and the curve.
    """
    if result["status"] != "ok":
        trial.set_user_attr("reason", result["reason"])
        study.tell(trial, state=optuna.trial.TrialState.FAIL)
        return {"params": params, "status": "failed", "reason": result["reason"]}
    misfit = relative_misfit(result["f60_n"], _target_of(spec))
    constraints = constraint_values(params, result["theta_sat_deg"], spec)
    for name, value in constraints.items():
        trial.set_constraint(name, value)
    # optuna-dashboard 0.21 reads only the older list format.
    trial.storage.set_trial_system_attr(trial._trial_id, "constraints", list(constraints.values()))
    for name, value in {
        "f60_n": result["f60_n"],
        "theta_sat_deg": result["theta_sat_deg"],
        "saturated": result["saturated"],
        "constraints": constraints,
        "feasible": is_feasible(constraints),
        "curve_angle_deg": result["angle_deg"],
        "curve_force_n": [round(f, 6) for f in result["force_n"]],
    }.items():
        trial.set_user_attr(name, value)
    study.tell(trial, misfit)
    return {
        "params": params,
        "status": "ok",
        "f60_n": result["f60_n"],
        "theta_sat_deg": result["theta_sat_deg"],
        "saturated": result["saturated"],
        "misfit": misfit,
        "constraints": constraints,
        "number": trial.number,
        "angle_deg": result["angle_deg"],
        "force_n": result["force_n"],
    }


def _record_of(trial: optuna.trial.FrozenTrial) -> dict[str, Any]:
    if trial.state != optuna.trial.TrialState.COMPLETE:
        return {
            "params": dict(trial.params),
            "status": "failed",
            "reason": trial.user_attrs.get("reason", ""),
        }
    attrs = trial.user_attrs
    return {
        "params": dict(trial.params),
        "status": "ok",
        "f60_n": attrs["f60_n"],
        "theta_sat_deg": attrs["theta_sat_deg"],
        "saturated": attrs["saturated"],
        "misfit": float(trial.value if trial.value is not None else np.inf),
        "constraints": dict(attrs["constraints"]),
        "number": trial.number,
        "angle_deg": attrs["curve_angle_deg"],
        "force_n": attrs["curve_force_n"],
    }


def _preference_key(params: dict[str, float], spec: StudySpec) -> tuple[float, ...]:
    return tuple(params[name] for name in spec.preference_order)


# -- the search on the surrogate -------------------------------------------------------------
def _search(model: Any, spec: StudySpec, iteration: int) -> pd.DataFrame:
    """An in-memory Optuna study on the surrogate: constrained, cheap trials."""
    target, tolerance = _target_of(spec), spec.targets.tolerance
    space = spec.space

    sampler = optuna.samplers.TPESampler(
        seed=spec.seed * 1000 + iteration,
        multivariate=True,
        n_startup_trials=min(40, spec.budget.surrogate_trials // 4),
    )
    search = optuna.create_study(direction="minimize", sampler=sampler)
    distributions = _distributions(spec)
    rows: list[dict[str, Any]] = []
    while len(rows) < spec.budget.surrogate_trials:
        trials = [search.ask(distributions) for _ in range(_SEARCH_BATCH)]
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
    offset = np.log(pred["f60_n"][i] / _target_of(spec))
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
    verifier: _Verifier,
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
            **point["params"],
            "f60_n": point["f60_n"],
            "theta_sat_deg": point["theta_sat_deg"],
        }
    n_ok = sum(r["status"] == "ok" for r in verifier.records.values())
    if point is not None and n_ok >= 3:
        # refit on every verified run, the last candidates included
        model = fit_surrogate(verifier.sample_set(), seed=spec.seed)
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
    attach_run_report(
        verifier.study,
        target_n=_target_of(spec),
        tolerance=spec.targets.tolerance,
        records=list(verifier.records.values()),
        chosen_number=None if chosen is None else chosen["number"],
        note=_note(spec, result),
    )
    return result


def _assess(
    spec: StudySpec,
    names: list[str],
    point: dict[str, Any],
    model: Any,
    good: np.ndarray,
    gradient: np.ndarray | None,
) -> dict[str, Any]:
    assessment = assess_identifiability(
        names,
        np.array([point["params"][n] for n in names]),
        lambda X: np.log(model.predict(X)["f60_n"]),
        good,
        tolerance=spec.targets.tolerance,
        preference_order=spec.preference_order,
        target_n=_target_of(spec),
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


def _equally_good(model: Any, spec: StudySpec, verifier: _Verifier, iterations: int) -> np.ndarray:
    names = verifier.names
    trials = _search(model, spec, iterations + 1)
    predicted = trials[trials.feasible & (trials.misfit <= spec.targets.tolerance)]
    verified = [[r["params"][n] for n in names] for r in verifier.meeting()]
    points = [predicted[names].to_numpy()]
    if verified:
        points.append(np.array(verified))
    return np.vstack(points)


def _message(
    spec: StudySpec,
    status: str,
    verifier: _Verifier,
    point: dict[str, Any] | None,
    calls_to_verify: int | None,
) -> str:
    target, tolerance = _target_of(spec), spec.targets.tolerance
    if status == "verified" and point is not None:
        return (
            f"verified: F60 = {point['f60_n']:.4g} N is within {100 * tolerance:g} % of "
            f"the target {target:.4g} N and every constraint holds, after "
            f"{calls_to_verify} full-solver runs"
        )
    if point is None:
        return (
            f"budget exhausted after {verifier.calls} runs and no solver run succeeded; "
            "check the rig and the parameter ranges"
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
        f"the best has F60 = {point['f60_n']:.4g} N "
        f"(misfit {100 * point['misfit']:.2f} %).{why}"
    )


def _reach(verifier: _Verifier) -> tuple[float, float] | None:
    values = [r["f60_n"] for r in verifier.records.values() if r["status"] == "ok"]
    return (min(values), max(values)) if values else None
