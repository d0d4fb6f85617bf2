"""``calibrate``: fit the coating and the enabled effects to measured curves.

The command over the loop's machinery (:mod:`._loop`; with an external full solver,
:mod:`._fidelity`'s corrected built-in model): the study and its measurements loaded,
the loop run, its best verified point judged (the first-order test, the F-test of the
misfit against the noise, what the curves determine), and the verifications recorded
as trials of ``<name>/calibrate/<model>`` with the result as the study's attribute.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.distributions import BaseDistribution

from .._errors import InputDataError
from .._log import show_progress
from .._pool import check_jobs, one_blas_thread_within
from .._validate import check_budget
from ..effects import get_effect
from ..identify._worker import HEARTBEAT_S
from ..solvers._fidelity import fidelity_record
from ..storage._optuna import distributions, quiet_optuna
from ..storage._storage import check_heartbeat, check_storage_url, open_storage
from ..study._design import conditions_text
from ..study._lab_files import sources_sha256
from ..study._space import ParameterSpace
from ..study._spec import StudySpec
from ._determination import at_bound_text, interval_text, parameter_interval_text
from ._fidelity import (
    LOW_FIDELITY_BUDGET,
    CorrectedCalibration,
    CorrectedRuns,
    CurveCorrection,
    Enough,
)
from ._local import LocalFit, bound_sides
from ._loop import (
    SETTLED,
    CalibrationLoop,
    SolverRuns,
    VerifiedPoint,
    determination_at,
    profiled_quantities,
)
from ._problem import (
    CalibrationProblem,
    calibration_study_name,
    load_calibration,
    model_label,
)
from ._statistics import SIGNIFICANCE

__all__ = [
    "CalibrationResult",
    "beaten_by",
    "beaten_text",
    "calibrate",
    "calibration_key",
    "calibration_note",
    "data_hash",
    "launched_runs",
    "recorded_calibration",
    "run_calibration",
]

_LOG = logging.getLogger(__name__)


# -- the result --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationResult:
    """Keys of ``surrogate calibrate --json``.

    ``params`` are the calibrated values (coating in the paper's units, effect
    parameters as ``effect.param``); ``rmse_n`` the RMSE over all measured
    points, verified by the full solver; ``solver_calls`` the full-solver runs
    this calibration used (a run already in the result cache is not repeated).

    ``status`` is ``converged`` only when the local phase's first-order test held
    at ``params`` (a verified point; see :mod:`surrogate.calibration._local`); else
    ``budget_exhausted`` where the budget is what stopped it (no further verification
    fitted in it), or ``stalled`` where it stopped with runs left (e.g. four rounds
    whose test found nothing better; the message says why): a larger budget would not
    have been spent.
    ``params`` is then the best verified point.
    ``predicted_gain`` is what that test measured: the relative RMSE decrease the
    Gauss–Newton model still promises within ±5 % of each range (``None`` unless
    ``converged``). With
    ``converged``: ``misfit`` is ``"within the noise"`` or ``"systematic"`` by the
    F-test of the RSS against the noise (``misfit_p_value``; systematic below
    0.01), and ``determination`` says what the curves determine (the keys of
    :class:`~surrogate.calibration._determination.Determination`: 95 % intervals of the
    bending stiffness ``bending_stiffness_nmm`` [N·mm per unit width], the plastic
    moment ``plastic_moment_n`` [N·mm/mm = N] and each parameter, the free
    parameters, those held at a bound). ``determination`` is ``None`` unless
    ``converged``. Unconverged, ``misfit`` is ``"within the noise"``
    where the best verified point already passes the F-test (a local optimum would fit
    at least as well: the model is not shown to miss anything), else ``None``: a
    misfit there may be the search's, not the model's.

    ``multi_fidelity`` (None for a built-in study): with an external full solver the
    corrected built-in model is searched (:mod:`surrogate.calibration._fidelity`);
    ``solver_calls`` counts the expensive runs, ``low_fidelity_runs`` the built-in ones,
    ``correction`` is its size at ``params``, ``dropped`` why it was not trusted (then the
    expensive solver's own local phase finished). ``converged`` then means: the
    first-order test of the corrected model held at a point the expensive solver
    verified, whose RMSE is the expensive solver's.

    ``basins``: whether other basins were searched before the result was reported and
    the local optima found (:class:`~surrogate.calibration._basins.BasinSearch`: where the
    best local optimum's misfit is systematic, the local phase restarts from diverse
    points within a share of the budget; ``optima`` best first). With an external full
    solver, the search ran on the corrected built-in model.

    ``next_test``: where ``surrogate next-test`` recommended a test on earlier data and
    these measurements hold it, the goal's predicted against its realised interval
    (``predicted_width``, ``realised_width`` in the goal's declared scale, ``ratio``);
    the message says so. None otherwise.

    ``retried``: the tests whose run at ``params`` the solver finished only after a
    retry (CalculiX: other increments, after the deck's own stopped short), each with why
    the earlier attempts stopped; the message says so. Near such points CalculiX's curves
    move by a few per cent between coatings 0.1 % apart — more than the noise — so a
    first-order test at the noise level may not hold there whatever the budget. Empty
    where every run was the deck's own (or the solver does not say: results cached
    before the solver reported it, the built-in solver).

    ``noise_n`` is the noise level σ the misfit is judged against (the replicates'
    pooled scatter, or ``[measurements] noise_n``); ``effects`` the model's effects;
    ``rmse_per_test_n`` the RMSE of each test [N]; ``iterations`` the global phase's
    verifications; ``study`` and ``storage`` the Optuna study
    ``<name>/calibrate/<model>`` and its storage; ``message`` the sentence the command
    prints.
    """

    params: dict[str, float]
    rmse_n: float
    noise_n: float
    solver_calls: int
    effects: list[str]
    rmse_per_test_n: dict[str, float]
    status: str
    predicted_gain: float | None
    misfit: str | None
    misfit_p_value: float | None
    determination: dict[str, Any] | None
    iterations: int
    study: str
    storage: str
    message: str
    multi_fidelity: dict[str, Any] | None = None
    retried: dict[str, str] = field(default_factory=dict)
    basins: dict[str, Any] | None = None
    next_test: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


# -- the command -------------------------------------------------------------------------------
@one_blas_thread_within
def calibrate(
    study: str | Path | StudySpec,
    *,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    max_solver_calls: int | None = None,
    jobs: int = 1,
    progress: bool = True,
    tests: Sequence[Any] | None = None,
    record: bool = True,
    launcher: str | None = None,
    heartbeat_s: int = HEARTBEAT_S,
) -> CalibrationResult:
    """Calibrate the coating and the enabled effects against the measured curves.

    Parameters
    ----------
    study : path or StudySpec
        A study with a ``[measurements]`` file.
    effects : sequence of str, optional
        Effects to enable; default: the study's ``[model] effects``.
    plugins : sequence of str
        Modules of user effects to import first (``--plugin``).
    storage : str, optional
        Optuna storage URL; default: the study's.
    max_solver_calls : int, optional
        Budget of full-solver runs (default: ``[budget] calibration_solver_calls``); one
        too small for the initial design and one verification (with an external solver
        and its built-in prior: for one verification) is refused before any run.
    jobs : int
        Worker processes for the runs of one verification (≥ 1).
    progress : bool
        Log each step at INFO (logger ``surrogate``; on stderr unless configured).
    tests : sequence, optional
        Calibrate on these tests only (used by the diagnosis).
    record : bool
        Keep the verifications as trials of ``<name>/calibrate/<model>``.
    launcher : str, optional
        ``slurm``: the external full solver's runs are jobs of the batch scheduler, one
        run a job, through the run queue ``<name>/runs`` (``jobs`` left at 1; the
        built-in solver's runs stay here). See :func:`launched_runs`.
    heartbeat_s : int
        The jobs' heartbeat interval [s] (a run silent for three is retried).

    Returns
    -------
    CalibrationResult
    """
    options: dict[str, Any] = {
        "effects": effects,
        "plugins": plugins,
        "storage": storage,
        "max_solver_calls": max_solver_calls,
        "jobs": jobs,
        "progress": progress,
        "tests": tests,
        "record": record,
    }
    with launched_runs(study, launcher, storage, jobs, heartbeat_s, plugins, progress) as queue:
        return run_calibration(study, **options, queue=queue)[0]


def launched_runs(
    study: str | Path | StudySpec,
    launcher: str | None,
    storage: str | None,
    jobs: int | None,
    heartbeat_s: int,
    plugins: Sequence[str],
    progress: bool,
) -> Any:
    """The run queue a command's expensive runs go through with ``--launcher``
    (:class:`surrogate.identify._runs.QueuedRuns`, a context manager), else a context
    of None; refused in one line before anything is written (``--jobs`` set, the
    built-in full solver, a launcher that refuses the jobs, a storage its nodes do not
    reach)."""
    if launcher is None:
        return contextlib.nullcontext()
    from ..identify._runs import prepare_queued_runs
    from ..study._spec import load_study

    check_heartbeat(heartbeat_s)
    if jobs not in (None, 1):
        raise InputDataError(
            f"--jobs {jobs} with --launcher {launcher}: the scheduler's jobs run the expensive "
            "runs (at most [cluster] max_jobs at once); drop --jobs"
        )
    spec = study if isinstance(study, StudySpec) else load_study(study)
    url = check_storage_url(storage or spec.default_storage())
    return prepare_queued_runs(
        launcher, spec, url, heartbeat_s=heartbeat_s, plugins=plugins, progress=progress
    )


def run_calibration(
    study: str | Path | StudySpec,
    *,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    max_solver_calls: int | None = None,
    jobs: int = 1,
    progress: bool = True,
    tests: Sequence[Any] | None = None,
    record: bool = True,
    correction: CurveCorrection | None = None,
    expensive: bool = True,
    certify: bool = True,
    start: Mapping[str, float] | None = None,
    queue: Any = None,
    intervals: bool = True,
    reuse: bool = False,
    enough: Enough | None = None,
) -> tuple[CalibrationResult, CalibrationLoop | None]:
    """:func:`calibrate`, and the loop it ran (the diagnosis reads its correction).

    With an external full solver: ``correction`` starts the corrected built-in model
    from earlier expensive runs; without ``expensive`` only that model is calibrated
    (built-in runs, nothing verified by the expensive solver: the diagnosis's
    recalibrations of candidates, never recorded); without ``certify`` a local optimum
    the corrected model's first-order test passed is not tested again by the expensive
    solver (the diagnosis's calibrations, whose runs name the effect); ``start`` (a study
    with the built-in solver only): the local phase begins there, no global phase (the
    diagnosis's recalibration of the model in a better basin it found). ``queue`` solves
    the expensive solver's runs (:func:`launched_runs`); without ``intervals`` no profile
    intervals are computed (the linear ones stand, unchecked: a diagnosis's candidates).
    With ``reuse``, the result recorded for the same :func:`calibration_key` stands where
    there is one, not run again; its loop is then None (the diagnosis's current model).
    ``enough`` (an external solver's loop): a rule that stops its expensive runs where the
    best verified point settles the caller's question (the diagnosis's).
    """
    check_jobs(jobs)
    check_budget(max_solver_calls)  # bad options fail before anything is read or written
    if progress:
        show_progress()
    spec, data, chosen, noise = load_calibration(study, effects, plugins)
    url = storage or spec.default_storage()
    check_storage_url(url)  # before the work, not after
    problem = CalibrationProblem(spec, data, chosen, tests=tests)
    cache = spec.directory / ".solver-cache"
    budget = max_solver_calls or spec.budget.calibration_solver_calls
    name = calibration_study_name(spec, chosen)
    key = None  # a key only for the calibration `calibrate` runs: recorded, from no start
    if record and expensive and intervals and start is None and correction is None:
        key = calibration_key(spec, chosen, budget, tests)
    recorded = recorded_calibration(url, name, key) if reuse else None
    if recorded is not None:
        if progress:
            _LOG.info(
                "[%s] the calibration recorded with the same study, data and code stands: "
                "not run again",
                name,
            )
        return recorded, None
    loop: CalibrationLoop
    if not spec.low_fidelity:
        runs = SolverRuns(problem, cache, jobs=jobs, queue=queue)
        loop = CalibrationLoop(
            problem, runs, noise=noise, budget=budget, progress=progress, label=name
        )
    elif expensive:
        runs = SolverRuns(problem, cache, jobs=jobs, queue=queue)
        loop = CorrectedCalibration(
            problem,
            runs,
            noise=noise,
            budget=budget,
            progress=progress,
            label=name,
            correction=correction,
            certify=certify,
            enough=enough,
        )
    else:
        runs = CorrectedRuns(problem, cache, jobs=jobs, correction=correction)
        loop = CalibrationLoop(
            problem, runs, noise=noise, budget=LOW_FIDELITY_BUDGET, progress=progress, label=name
        )
    loop.intervals = intervals  # the profile intervals (a diagnosis's candidates need none)
    smallest, made_of = loop.smallest_budget()
    if expensive and budget < smallest:
        if record:  # the user's calibration: refused before any run, not overshot
            where = "--budget" if max_solver_calls else "[budget] calibration_solver_calls"
            raise InputDataError(
                f"{where} {budget} is too small for this calibration: it needs at least "
                f"{smallest} solver runs ({made_of}); raise it"
            )
        # a diagnosis's recalibration with a candidate's extra parameters: its initial
        # design and one verification, as the model it is ranked against had
        loop.budget = smallest
    if start is None:
        loop.run(spec.budget.surrogate_trials)
    elif type(loop) is CalibrationLoop:
        loop.run(spec.budget.surrogate_trials, np.array([start[n] for n in problem.space.names]))
    else:
        raise ValueError("a calibration from a start point needs the built-in solver's loop")
    result = _result(loop, chosen, url)
    if record and expensive:
        checked = next_test_check(url, name, problem, result, data_hash(spec))
        if checked is not None:
            result = replace(
                result, next_test=checked, message=f"{result.message}; {checked['sentence']}"
            )
        stopped = isinstance(loop, CorrectedCalibration) and loop.settled is not None
        _record(result.storage, name, problem, loop.verified, result, data_hash(spec), key, stopped)
    return result, loop


def next_test_check(
    url: str,
    name: str,
    problem: CalibrationProblem,
    result: CalibrationResult,
    data_sha: str,
) -> dict[str, Any] | None:
    """Where ``surrogate next-test`` recommended a test on other data and the measurements
    now hold a test at its conditions: the goal's predicted interval against the one this
    calibration found (``{conditions, goal, predicted_width, realised_width, ratio,
    sentence}``, widths in the goal's declared scale); else None."""
    if result.determination is None:
        return None
    try:
        study = optuna.load_study(study_name=name, storage=open_storage(url))
    except KeyError:
        return None
    recorded = study.user_attrs.get("next_test")
    if not recorded or recorded.get("data_sha256") == data_sha or not recorded["recommended"]:
        return None
    best, goal = recorded["recommended"][0], recorded["goal"]
    entries = {**result.determination["combinations"], **result.determination["intervals"]}
    quantities = {q.name: q for q in profiled_quantities(problem)}
    if goal not in entries or goal not in quantities or not _measured(problem, best["conditions"]):
        return None
    quantity, entry = quantities[goal], entries[goal]
    low, high = quantity.range_scaled
    realised = (high if entry["high"] is None else quantity.scale(entry["high"])) - (
        low if entry["low"] is None else quantity.scale(entry["low"])
    )
    predicted = best["predicted"][goal]["width_after"]
    ratio = realised / predicted if predicted > 0 else math.inf
    conditions = conditions_text(best["conditions"])
    return {
        "conditions": best["conditions"],
        "goal": goal,
        "predicted_width": predicted,
        "realised_width": realised,
        "ratio": ratio,
        "sentence": (
            f"the test next-test recommended ({conditions}) was predicted to settle {goal} "
            f"to {best['predicted'][goal]['precision']}; with it the interval is "
            f"{interval_text(entry)}, {ratio:.2g} × the predicted width"
        ),
    }


def _measured(problem: CalibrationProblem, conditions: Mapping[str, Any]) -> bool:
    """Whether a measured test was run at ``conditions`` (numbers to 1e-6 relative)."""
    for test_id in problem.test_ids:
        have = problem.data.conditions_of(test_id)
        if all(
            (have.get(k) == v)
            if isinstance(v, str)
            else math.isclose(float(have.get(k, math.nan)), float(v), rel_tol=1e-6, abs_tol=1e-9)
            for k, v in conditions.items()
        ):
            return True
    return False


def _result(loop: CalibrationLoop, effects: Sequence[str], url: str) -> CalibrationResult:
    """The result of a finished loop: its best verified point, and what the first-order
    test and the statistics say there."""
    problem, runs, name = loop.problem, loop.runs, loop.label
    fit, best = loop.best_fit(), loop.best()
    if best is None:
        reason = runs.failures[0] if runs.failures else "no verification fitted in the budget"
        all_spent = (  # a budget of one verification has no run left for another point
            f"all {loop.budget} solver runs of the budget were spent: raise --budget, or "
            if runs.failures and loop.budget_spent()
            else ""
        )
        raise InputDataError(
            f"calibration of {name} found no parameter point the solver could run at every "
            f"test ({reason}); {all_spent}check the parameter ranges"
        )
    converged = loop.converged_at_best()
    misfit, p_value, determination = None, None, None
    if fit is not None and converged:
        p_value = loop.p_value(fit)
        misfit = "within the noise" if p_value >= SIGNIFICANCE else "systematic"
        found = (
            loop.determination if loop.determination is not None else determination_at(problem, fit)
        )
        determination = found.to_json()
    elif (at_best := loop.p_value_at(best)) >= SIGNIFICANCE:  # an optimum fits as well
        p_value, misfit = at_best, "within the noise"
    spent = loop.budget_spent()
    result = CalibrationResult(
        params=dict(zip(problem.space.names, map(float, best.theta), strict=True)),
        rmse_n=float(best.rmse),
        noise_n=loop.noise,
        solver_calls=loop.calibration_calls,
        effects=list(effects),
        rmse_per_test_n=best.per_test,
        status="converged" if converged else "budget_exhausted" if spent else "stalled",
        predicted_gain=fit.predicted_gain if fit is not None and converged else None,
        misfit=misfit,
        misfit_p_value=p_value,
        determination=determination,
        iterations=loop.iterations,
        study=name,
        storage=url,
        message="",
    )
    stopped = loop.settled if isinstance(loop, CorrectedCalibration) else None
    message = _message(problem, result, fit, loop.basins.sentence(loop.noise), stopped)
    retried, sentence = _retried(loop, best)
    message += sentence
    multi = _multi_fidelity(loop, best)
    if multi is not None:
        message += multi.pop("sentence")
        if isinstance(loop, CorrectedCalibration) and misfit is not None:
            message += loop.basin_caveat(misfit == "systematic")
    return replace(
        result,
        message=message,
        multi_fidelity=multi,
        retried=retried,
        basins=loop.basins.to_json(),
    )


def _retried(loop: CalibrationLoop, best: VerifiedPoint) -> tuple[dict[str, str], str]:
    """The tests whose run at ``best`` the solver finished only after a retry (its
    result's ``retried_after``): test id → why the earlier attempts stopped; and the
    sentence the message adds ("" where there are none)."""
    problem = loop.problem
    results = [loop.runs.cache.get(key) or {} for key in best.keys]  # by condition group
    said = {
        str(test_id): str(results[group]["retried_after"])
        for test_id, group in zip(problem.test_ids, problem.test_group, strict=True)
        if results[group].get("retried_after")
    }
    if not said:
        return said, ""
    finished = sorted(
        {str(r["increments"]) for r in results if r.get("retried_after") and r.get("increments")}
    )
    how = f" ({', '.join(finished)})" if finished else ""
    return said, (
        f"; {problem.spec.solver} finished test(s) {', '.join(said)} at this point only "
        f"after a retry{how}: near such points its curves move by a few per cent between "
        "coatings 0.1 % apart, more than the noise, so a local optimum at the noise level "
        "may not be verifiable here (`retried` says why the first attempts stopped)"
    )


def _multi_fidelity(loop: CalibrationLoop, best: VerifiedPoint) -> dict[str, Any] | None:
    """The ``multi_fidelity`` record with its sentence (None unless the loop corrected
    the built-in model towards an external solver)."""
    if not isinstance(loop, CorrectedCalibration):
        return None
    kind = loop.problem.spec.solver
    then = (
        f"{kind}'s own calibration took over"
        if loop.single_fidelity
        else f"{kind}'s own local phase went on from the best verified point"
        if loop.settled is None
        else f"nothing more ran on {kind} (stopped by a diagnosis's rule)"
    )
    record = fidelity_record(
        kind,
        loop.low_fidelity_runs,
        loop.correction_at(best),
        loop.dropped,
        loop.dropped_after,
        then,
    )
    fit = loop.best_fit()
    tested_by = None
    if fit is not None and loop.converged_at_best():
        tested_by = "corrected model" if loop.by_corrected_model(fit) else kind
    record["optimum_tested_by"] = tested_by
    partly = loop.tested_partly(fit) if fit is not None and tested_by == kind else None
    record["tested_along"] = None if partly is None else {"own": partly[0], "corrected": partly[1]}
    if partly is not None:
        own, borrowed, runs = partly
        record["sentence"] += (
            f". The first-order test that held is {kind}'s own along {own} (a Jacobian of "
            f"{runs} {kind} runs) and the corrected model's along {borrowed}, on which the "
            f"curves hardly depend: the intervals are {kind}'s along {own}"
        )
    elif tested_by == kind:
        record["sentence"] += (
            f". The first-order test that held is {kind}'s own (a Jacobian of "
            f"{loop.jacobian_runs} {kind} runs), so the intervals are {kind}'s"
        )
    elif tested_by == "corrected model":
        record["sentence"] += (
            f". The first-order test that held is the corrected model's, so the intervals "
            f"are its own and may miss {kind}'s optimum: {kind}'s own test "
            f"({loop.jacobian_runs} runs) "
            + (
                "is left to `surrogate calibrate` (a diagnosis spends its runs on naming "
                "the effect)"
                if not loop.certify
                else f"did not fit in the budget ({loop.short}): raise --budget to certify it"
                if loop.short
                else "did not finish (the progress log says why)"
            )
        )
    return record


def unconverged_reason(result: CalibrationResult, fit: LocalFit | None) -> str | None:
    """Why a calibration ended before a verified local optimum (None: it reached one):
    the local fit's own words where it ended at the reported point."""
    if result.status == "converged":
        return None
    reported = np.array(list(result.params.values()))
    if fit is not None and np.array_equal(fit.theta, reported):
        return fit.message
    return "no local fit ended at the best verified point"


def _message(
    problem: CalibrationProblem,
    result: CalibrationResult,
    fit: LocalFit | None,
    basins: str = "",
    stopped: str | None = None,
) -> str:
    """The calibration's one message. Unconverged: the local fit's reason, and "raise
    --budget" only where the budget is what stopped it (``budget_exhausted``; converged,
    where it left no run for the search of other basins: ``basins``); a fit
    that stopped with runs left (``stalled``: four rounds whose test found nothing
    better) says that more runs would not have been spent there. ``basins``: what the
    search of other basins found (:meth:`~._basins.BasinSearch.sentence`), after the
    status."""
    rmse, noise = result.rmse_n, result.noise_n
    text = (
        f"{model_label(result.effects)}: RMSE {rmse:.4g} N over {problem.n_points} points of "
        f"{len(problem.test_ids)} tests, noise {noise:.4g} N ({rmse / noise:.2f}× noise), "
        f"{result.solver_calls} solver calls, {result.status}"
    )
    why = unconverged_reason(result, fit)
    if why is not None:
        hint = (
            "raise --budget"
            if result.status == "budget_exhausted"
            else f"its expensive runs were stopped by a diagnosis's rule: {stopped}"
            if stopped is not None
            else "the budget was not the limit: a larger one would not have been spent"
        )
        text = f"{text} ({why}; best verified point so far — {hint}){basins}"
        text += _at_bounds(problem, result.params)
        if result.misfit is None:
            return text
        return (
            f"{text}; its misfit is already within the noise (F-test p = "
            f"{result.misfit_p_value:.2g}), so a local optimum fits at least as well; "
            "what the curves determine is stated only at a verified local optimum"
        )
    assert result.determination is not None
    held = [n for n in result.determination["held_at_bound"] if n in problem.spec.space.names]
    return (
        f"{text} ({fit.message if fit else ''}){basins}; {result.misfit} (F-test p = "
        f"{result.misfit_p_value:.2g}); {result.determination['statement']}"
        + (f" — {_widen(len(held))}" if held else "")
    )


def _at_bounds(problem: CalibrationProblem, params: Mapping[str, float]) -> str:
    """Where the best point of an unconverged calibration lies on a bound of a range the
    study file declares, that it does and what would tell ("" where none does): the
    search does not look beyond it, and a better fit may lie there (or in another basin).
    An effect's parameters are left out: their ranges are the effect's own (0 is the
    effect switched off), not the study's to widen."""
    space = problem.spec.space
    sides = declared_bound_sides(space, params)
    on = [
        at_bound_text(p.name, int(side), p.low if side < 0 else p.high, "at")
        for p, side in zip(space, sides, strict=True)
        if side != 0
    ]
    if not on:
        return ""
    listed = on[0] if len(on) == 1 else f"{', '.join(on[:-1])} and {on[-1]}"
    return f"; its {listed} — {_widen(len(on))}"


def declared_bound_sides(space: ParameterSpace, params: Mapping[str, float]) -> np.ndarray:
    """:func:`~._local.bound_sides` of the parameters the study file declares (``space``,
    in its order) at a point ``params`` that may hold an effect's too."""
    return bound_sides(space.to_unit(np.array([[params[name] for name in space.names]]))[0])


def _widen(count: int) -> str:
    """What would tell whether a fit beyond ``count`` ranges of the study file is better."""
    return (
        f"the search stops at the declared ranges: widen {'them' if count > 1 else 'it'} "
        "in the study file to see whether a fit beyond is better"
    )


def data_hash(spec: StudySpec) -> str:
    """SHA-256 of the measurements' bytes (which data a calibration saw; one file's is
    its bytes')."""
    assert spec.measurements_file is not None
    return sources_sha256(spec.measurements_file, spec.measurement_format)


def calibration_key(
    spec: StudySpec,
    effects: Sequence[str],
    budget: int,
    tests: Sequence[Any] | None,
) -> str | None:
    """SHA-256 of everything a built-in study's calibration follows from: the study as
    loaded, the model's effects, the budget, the tests calibrated on, the measurements'
    bytes, the package's source, Python's and the numerical libraries' versions (the
    calibration is deterministic given these: tests/test_calibrate_sweep.py). None where
    that cannot be said here: an external solver (its program's version is not known
    here; with the built-in prior, the diagnosis needs the loop's correction too) and an
    effect that is not the package's own (a plug-in's code is not hashed)."""
    if spec.solver != "builtin" or spec.measurements_file is None:
        return None
    if any(not type(get_effect(e)).__module__.startswith("surrogate.") for e in effects):
        return None
    import llvmlite
    import numba
    import scipy
    import sklearn

    digest = hashlib.sha256()
    for part in (repr(spec), repr(list(effects)), str(budget), repr(tests), data_hash(spec)):
        digest.update(part.encode() + b"\0")
    digest.update(f"{sys.version}\0".encode())
    for library in (np, scipy, sklearn, optuna, numba, llvmlite):
        digest.update(f"{library.__name__} {library.__version__}\0".encode())
    package = Path(__file__).resolve().parents[1]
    for source in sorted(package.rglob("*.py")):
        digest.update(f"{source.relative_to(package)}\0".encode() + source.read_bytes())
    return digest.hexdigest()


def recorded_calibration(url: str, name: str, key: str | None) -> CalibrationResult | None:
    """The result the calibration study ``name`` recorded where its :func:`calibration_key`
    is ``key`` (the same calibration, run before: ``surrogate calibrate`` then
    ``surrogate diagnose``); else None (never recorded, another key, or ``key`` None)."""
    if key is None:
        return None
    try:
        study = optuna.load_study(study_name=name, storage=open_storage(url))
    except KeyError:
        return None
    attrs = study.user_attrs
    if attrs.get("calibration_key") != key or "result" not in attrs:
        return None
    return CalibrationResult(**attrs["result"])


# -- the record in the Optuna storage -----------------------------------------------------------
def _record(
    url: str,
    name: str,
    problem: CalibrationProblem,
    verified: list[VerifiedPoint],
    result: CalibrationResult,
    data_sha: str,
    inputs_key: str | None,
    stopped: bool = False,
) -> None:
    """Verifications as trials of the study ``name``; the result as a study attribute,
    with the :func:`calibration_key` of its inputs (None: not one to reuse) — except where
    a rule ``stopped`` the calibration short (a diagnosis's) and an earlier result stands:
    the trials only."""
    quiet_optuna()
    study = optuna.create_study(study_name=name, storage=open_storage(url), load_if_exists=True)
    known = {
        t.user_attrs.get("verification_key")
        for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    }
    trial_distributions: dict[str, BaseDistribution] = dict(distributions(problem.space))
    for item in verified:
        key = hashlib.sha256("".join(item.keys).encode()).hexdigest()
        if key in known:
            continue
        inside = problem.space.clip(item.theta)
        params = dict(zip(problem.space.names, map(float, inside), strict=True))
        known.add(key)
        trial = optuna.trial.create_trial(
            params=params,
            distributions=trial_distributions,
            value=item.rmse,
            user_attrs={
                "verification_key": key,
                "phase": item.phase,
                "predicted_rmse_n": item.predicted,
                "rmse_per_test_n": item.per_test,
                "solver_calls": item.calls,
                "effects": list(problem.effects),
                "data_sha256": data_sha,
            },
        )
        study.add_trial(trial)
    if stopped and "result" in study.user_attrs:
        return
    study.set_user_attr("result", json.loads(json.dumps(result.to_json())))
    study.set_user_attr("data_sha256", data_sha)
    study.set_user_attr("calibration_key", inputs_key)
    _note(study, calibration_note(result.to_json()))


def beaten_by(
    storage: str | optuna.storages.BaseStorage, name: str, result: Mapping[str, Any]
) -> dict[str, Any] | None:
    """The best verified point of the calibration study ``name`` on the same data, where it
    fits better than the recorded ``result`` by more than ``SETTLED`` of its RMSE (another
    basin the recorded calibration did not reach: an earlier run's, with another seed or
    budget): ``{trial, rmse_n, params}``; else None."""
    if isinstance(storage, str):
        storage = open_storage(storage)
    try:
        study = optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        return None
    data = study.user_attrs.get("data_sha256")
    trials = [
        t
        for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
        if t.value is not None and t.user_attrs.get("data_sha256") == data
    ]
    values = [float(t.value) for t in trials if t.value is not None]
    if not values or min(values) >= (1.0 - SETTLED) * result["rmse_n"]:
        return None
    best = trials[int(np.argmin(values))]
    return {"trial": best.number, "rmse_n": min(values), "params": dict(best.params)}


def beaten_text(model: str, beaten: Mapping[str, Any], noise: float) -> str:
    """The one line that says another basin beats a recorded calibration."""
    values = ", ".join(f"{k}={v:.4g}" for k, v in beaten["params"].items())
    return (
        f"another basin beats this calibration of {model}: verified point #{beaten['trial']} "
        f"of its study fits to {beaten['rmse_n']:.4g} N ({beaten['rmse_n'] / noise:.3g} × "
        f"noise) at {values}"
    )


def calibration_note(result: Mapping[str, Any]) -> list[str]:
    """The calibration's status and what the curves determine, as Markdown lines
    (the dashboard note of the calibration study; compare and diagnose repeat it)."""
    lines = [f"## Calibration: {result['status']}", "", result["message"]]
    determination = result.get("determination")
    if determination:
        lines += ["", "| quantity | value | 95 % interval |", "|---|---|---|"]
        for key, c in determination["combinations"].items():
            lines.append(f"| {key} | {c['value']:.4g} | {interval_text(c)} |")
        for name, value in result["params"].items():
            span = parameter_interval_text(name, determination)
            lines.append(f"| {name} | {value:.4g} | {span} |")
    return lines


def _note(study: optuna.Study, lines: list[str]) -> None:
    """Markdown note of the study in optuna-dashboard (skipped without it)."""
    try:
        from optuna_dashboard import save_note
    except ImportError:
        return
    save_note(study, "\n".join(lines))
