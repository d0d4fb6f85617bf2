"""``diagnose``: where the model fails, which physical effect is missing.

1. **Calibrate** the current model (``calibrate``; each calibration of a study is
   a step of its *model ladder* in the Optuna storage).
2. **Where it fails.** The residuals at the calibrated point are set against the
   noise level by F-tests — ``(RSS/dof) / s²`` with the noise's own degrees of
   freedom (replicates), so a noise level estimated from few replicates does not
   raise false alarms: overall, per test, per angle band and per value of each
   condition (Bonferroni over the cells).
3. **What the residual follows.** For each condition, covariate and the angle:
   a weighted regression of the tests' mean residual on that column (the angle:
   of every residual on a cubic in the angle), F-tested against what it leaves
   unexplained (at least the noise), Bonferroni over the columns. With ten-odd
   tests a GP with one length scale per covariate has too little to learn from;
   one-at-a-time regressions are what such data support, and they say plainly
   which column the misfit follows.
4. **Which effect is missing.** Every candidate effect not in the model (built-ins
   and registered plug-ins), whose test condition varies in the data, is added and
   recalibrated *locally* with the full solver (a bounded trust-region least-squares
   fit from the calibrated point, finite-difference Jacobian: ``(p+1)·G`` solver
   runs an iteration; the candidates in parallel processes); its held-out error
   comes from leaving one test out of the linearised fit at the optimum (a ridge
   refit on the other tests), and its BIC penalises the extra parameters.
   Candidates are ranked by ΔBIC (best first). A local refit stays in the basin of
   the current model's optimum, so the leader — and every candidate within ΔBIC
   10 of it — is recalibrated over the whole space (:func:`calibrate`, not kept
   as a ladder step) and polished locally again.
5. **Verdict.** An effect is named only when it is decisive (ΔBIC < −10) *and*
   cuts the held-out error by at least 10 %; candidates within ΔBIC 10 of it are
   reported as fitting as well (``tied_with``: the data cannot tell them apart —
   ``hardening`` and ``membrane_bending`` are the same moment–curvature law).
   When none brings the error near the noise level, the column the residual
   follows is named instead.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from scipy import stats

from .._errors import InputDataError
from ..effects import available_effects, get_effect
from ._compare import BANDS, _bands, column_values
from ._local import ResidualModel, SolverFailed, local_fit
from ._loop import (
    CalibrationProblem,
    _load,
    _Runs,
    calibrate,
    calibration_note,
    calibration_study_name,
    model_label,
)
from ._statistics import SIGNIFICANCE, bic, misfit_p_value, noise_dof

__all__ = ["DiagnosisResult", "diagnose", "model_ladder"]

DECISIVE_DELTA_BIC = -10.0  # "very strong" evidence (Kass & Raftery 1995)
HELDOUT_GAIN = 0.9  # a named effect cuts the held-out RMSE by ≥ 10 %
NEAR_NOISE = 1.3  # an RMSE within 1.3× noise is explained
_LOCAL_EVALS = 40  # residual evaluations of one local refit (each G solver runs)
LOO_PRIOR_UNIT = 0.05  # prior SD of a parameter in the held-out refits, fraction of its range


@dataclass(frozen=True)
class DiagnosisResult:
    """Keys of ``surrogate diagnose --json``.

    ``ranking`` is best first; ``tied_with`` lists the candidates that fit as
    well as the first (ΔBIC within 10 of it); ``follows`` the columns the
    residual follows, strongest first; ``ladder`` every calibration of the study.
    """

    rmse_n: float
    noise_n: float
    systematic: bool
    p_value: float
    where: list[dict[str, Any]]
    follows: list[dict[str, Any]]
    ranking: list[dict[str, Any]]
    tied_with: list[str]
    unexplained: dict[str, Any] | None
    verdict: str
    effects: list[str]
    heldout_rmse_n: float
    solver_calls: int
    ladder: list[dict[str, Any]]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def diagnose(
    study: Any,
    *,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    candidates: Sequence[str] | None = None,
    jobs: int | None = None,
    progress: bool = True,
) -> DiagnosisResult:
    """Calibrate the model, test its misfit against the noise, rank missing effects.

    Parameters
    ----------
    study : path or StudySpec
        A study with ``[measurements]``.
    effects : sequence of str, optional
        The current model's effects (default: the study's ``[model] effects``).
    candidates : sequence of str, optional
        Effects to try (default: every registered effect not in the model).
    jobs : int, optional
        Processes for the local refits (default: the machine's CPUs).
    """
    _jobs(jobs, 1)  # a bad value fails before any work
    spec, data, chosen, noise = _load(study, effects, plugins)
    url = storage or spec.default_storage()
    say = _Say(progress, f"{spec.name}/diagnose")
    fitted = calibrate(spec, effects=chosen, storage=url, progress=progress)
    problem = CalibrationProblem(spec, data, chosen)
    names = _candidates(problem, chosen, candidates)
    # the current model gets the same local refit as every candidate, so ΔBIC compares
    # like with like; the refits are independent, one process each
    tasks = [(spec, data, chosen, None, fitted.params, noise)]
    tasks += [(spec, data, (*chosen, name), name, fitted.params, noise) for name in names]
    say(f"refitting the model and {len(names)} candidate effects locally with the full solver")
    refits: dict[str | None, _Refit] = {}
    for refit in _map(_refit, tasks, _jobs(jobs, len(tasks))):
        refits[refit.effect] = refit
        if refit.effect is not None:
            say(f"+ {refit.effect}: RMSE {refit.rmse:.4g} N, held-out {refit.heldout_rmse:.4g} N")
    current = refits[None]
    theta = current.theta
    dof_noise = noise_dof(spec.noise_n is not None, data.noise_dof)
    n_points = problem.n_points
    residual = current.residual
    rss = float(residual @ residual)
    rmse = math.sqrt(rss / problem.n_points)
    p_value = misfit_p_value(rss, n_points - len(theta), noise, dof_noise)
    systematic = p_value < SIGNIFICANCE
    where = _where(problem, residual, current.curves, noise, dof_noise)
    follows = _follows(problem, residual, noise)
    say(
        f"model {model_label(chosen)}: RMSE {rmse:.4g} N, noise {noise:.4g} N, "
        f"{'systematic' if systematic else 'within the noise'} (p = {p_value:.2g})"
    )
    ranking = []
    base_bic = bic(rss, n_points, len(theta))
    used = set(current.used)
    solver_calls = fitted.solver_calls

    def entry_of(name: str, fit: _Refit) -> dict[str, Any]:
        fit_rss = float(fit.residual @ fit.residual)
        return {
            "effect": name,
            "rmse_n": math.sqrt(fit_rss / n_points),
            "heldout_rmse_n": fit.heldout_rmse,
            "delta_bic": bic(fit_rss, n_points, len(fit.theta)) - base_bic,
            "params": fit.params,
        }

    for name in names:
        used |= refits[name].used
        ranking.append(entry_of(name, refits[name]))
    ranking.sort(key=lambda e: e["delta_bic"])
    if systematic and ranking:
        # A local refit stays in the basin of the current model's optimum (the coat's
        # third parameter can sit in another; a compliant clamp needs a much stiffer
        # coat than the model without it found). So the leaders are recalibrated over
        # the whole space — and, before the verdict can be "unexplained", every other
        # candidate too.
        leaders = [e["effect"] for e in ranking if _tied(e, ranking[0])]
        done: set[str] = set()
        for names_now in (leaders, [e["effect"] for e in ranking]):
            todo = [name for name in names_now if name not in done]
            if not todo or (done and _named(ranking[0], current.heldout_rmse, noise)):
                continue
            say(f"recalibrating with {', '.join(todo)} over the whole parameter space")
            tasks = [(spec, data, (*chosen, name), name, noise) for name in todo]
            for again, calls in _map(_recalibrate, tasks, _jobs(jobs, len(tasks))):
                solver_calls += calls
                if again is None:
                    continue
                used |= again.used
                if again.rmse < refits[again.effect].rmse:
                    refits[again.effect] = again
            done.update(todo)
            ranking = sorted(
                (entry_of(e["effect"], refits[e["effect"]]) for e in ranking),
                key=lambda e: e["delta_bic"],
            )
    # candidates not decisively worse than the best: the data cannot tell them apart
    tied = [e["effect"] for e in ranking[1:] if _tied(e, ranking[0])]
    named = systematic and bool(ranking) and _named(ranking[0], current.heldout_rmse)
    unexplained, verdict = _verdict(
        rmse, current.heldout_rmse, noise, systematic, p_value, ranking, follows, tied
    )
    _record_heldout(url, calibration_study_name(spec, chosen), current.heldout_rmse)
    result = DiagnosisResult(
        rmse_n=rmse,
        noise_n=noise,
        systematic=systematic,
        p_value=p_value,
        where=where,
        follows=follows,
        ranking=ranking,
        tied_with=tied if named else [],
        unexplained=unexplained,
        verdict=verdict,
        effects=list(chosen),
        heldout_rmse_n=current.heldout_rmse,
        solver_calls=solver_calls + len(used),
        ladder=model_ladder(url, spec.name),
    )
    _attach_ladder(url, calibration_study_name(spec, chosen), result, fitted.to_json())
    say(verdict)
    return result


def _attach_ladder(
    url: str, name: str, result: DiagnosisResult, calibration: dict[str, Any]
) -> None:
    """The ladder and the verdict on the calibration study, for optuna-dashboard (below
    the calibration's own statement)."""
    try:
        import plotly.graph_objects as go
        from optuna_dashboard import save_note, save_plotly_graph_object
    except ImportError:
        return
    study = optuna.load_study(study_name=name, storage=url)
    ladder = result.ladder
    figure = go.Figure()
    models = [s["model"] for s in ladder]
    figure.add_trace(go.Scatter(x=models, y=[s["rmse_n"] for s in ladder], name="RMSE"))
    figure.add_trace(
        go.Scatter(x=models, y=[s["heldout_rmse_n"] for s in ladder], name="held-out RMSE")
    )
    figure.add_trace(
        go.Scatter(x=models, y=[result.noise_n] * len(ladder), name="noise", mode="lines")
    )
    figure.update_layout(
        title="Model ladder", yaxis_title="error [N]", yaxis_type="log", xaxis_title="model"
    )
    save_plotly_graph_object(study, figure, graph_object_id="model-ladder")
    rows = [
        f"| {e['effect']} | {e['rmse_n']:.4g} | {e['heldout_rmse_n']:.4g} | {e['delta_bic']:.1f} |"
        for e in result.ranking
    ]
    save_note(
        study,
        "\n".join(
            [
                f"## Diagnosis: {result.verdict}",
                "",
                "| added effect | RMSE [N] | held-out RMSE [N] | ΔBIC |",
                "|---|---|---|---|",
                *rows,
                "",
                *calibration_note(calibration),
            ]
        ),
    )


class _Say:
    def __init__(self, on: bool, label: str) -> None:
        self.on, self.label = on, label

    def __call__(self, text: str) -> None:
        if self.on:
            print(f"[{self.label}] {text}", file=sys.stderr, flush=True)


# -- where the model fails ----------------------------------------------------------------------
def _where(
    problem: CalibrationProblem,
    residual: np.ndarray,
    curves: np.ndarray,
    noise: float,
    dof_noise: float,
) -> list[dict[str, Any]]:
    """Cells (tests, angle bands, condition values) whose misfit the noise does not explain."""
    cells: list[tuple[str, str, np.ndarray]] = []
    for index, test_id in enumerate(problem.test_ids):
        cells.append(("test", str(test_id), problem.point_test == index))
    band = _bands(problem, curves)
    for index, label in enumerate(BANDS):
        if np.any(band == index):
            cells.append(("angle band", label, band == index))
    table = problem.data.tests.set_index("test_id")
    for column in problem.data.conditions:
        values = [table.loc[t, column] for t in problem.test_ids]
        if len(set(values)) < 2:
            continue
        for value in sorted(set(values), key=str):
            tests = [i for i, v in enumerate(values) if v == value]
            cells.append((column, str(value), np.isin(problem.point_test, tests)))
    found = []
    for kind, name, mask in cells:
        r = residual[mask]
        p = misfit_p_value(float(r @ r), r.size, noise, dof_noise)
        if p * len(cells) < SIGNIFICANCE:
            found.append(
                {
                    "kind": kind,
                    "name": name,
                    "rmse_n": float(np.sqrt(np.mean(r**2))),
                    "bias_n": float(np.mean(r)),
                    "p_value": min(1.0, p * len(cells)),
                }
            )
    return sorted(found, key=lambda c: -c["rmse_n"])


def _numeric(values: list[Any], column: str) -> np.ndarray | None:
    """:func:`column_values`, with the rate on a log scale (the rate effect's own axis)."""
    x = column_values(values)
    if x is None or column != "rate_deg_s" or np.any(x <= 0):
        return x
    return np.log(x)


def _follows(
    problem: CalibrationProblem, residual: np.ndarray, noise: float
) -> list[dict[str, Any]]:
    """Which columns the residual follows, strongest first (Bonferroni-corrected p).

    Each column in turn: a weighted regression of the tests' mean residual on it
    (weights: the tests' point counts), F-tested against what it leaves unexplained
    — or against the noise, whichever is larger — so a decoy that merely
    correlates a little with the real cause is not reported while the misfit is
    far above the noise. The angle: every residual on a cubic in the angle.
    """
    n_tests = len(problem.test_ids)
    counts = np.bincount(problem.point_test, minlength=n_tests).astype(float)
    bias = np.bincount(problem.point_test, residual, n_tests) / counts
    table = problem.data.tests.set_index("test_id")
    found = []
    for column in (*problem.data.conditions, *problem.data.covariates):
        x = _numeric([table.loc[t, column] for t in problem.test_ids], column)
        if x is None or np.ptp(x) == 0 or n_tests < 3:
            continue
        design = np.column_stack([np.ones(n_tests), x])
        found.append(_regression(column, design, bias, counts, noise))
    angle = problem.point_angle_deg / 90.0
    design = np.column_stack([np.ones_like(angle), angle, angle**2, angle**3])
    found.append(_regression("angle_deg", design, residual, np.ones_like(residual), noise))
    for entry in found:
        entry["p_value"] = min(1.0, entry["p_value"] * len(found))
        entry["significant"] = entry["p_value"] < SIGNIFICANCE
    return sorted(found, key=lambda e: (e["p_value"], -e["f_stat"]))


def _regression(
    name: str, design: np.ndarray, y: np.ndarray, weights: np.ndarray, noise: float
) -> dict[str, Any]:
    """F-test of a weighted least-squares fit against a constant; noise as the floor."""
    w = np.sqrt(weights)
    coef, *_ = np.linalg.lstsq(design * w[:, None], y * w, rcond=None)
    fitted = design @ coef
    mean = np.average(y, weights=weights)
    k = design.shape[1] - 1
    explained = float(np.sum(weights * (fitted - mean) ** 2)) / k
    dof = y.size - design.shape[1]
    scatter = float(np.sum(weights * (y - fitted) ** 2)) / max(dof, 1)
    f_stat = explained / max(scatter, noise**2)
    p = float(stats.f.sf(f_stat, k, dof)) if dof > 0 else 1.0
    return {"covariate": name, "p_value": p, "f_stat": f_stat, "slope_n": float(coef[1])}


# -- local refits with the full solver -----------------------------------------------------------
@dataclass
class _Refit:
    """One model (the current one, ``effect=None``, or it plus a candidate) refitted locally."""

    effect: str | None
    theta: np.ndarray
    params: dict[str, float]
    residual: np.ndarray
    curves: np.ndarray
    heldout_rmse: float
    used: set[str]

    @property
    def rmse(self) -> float:
        return float(np.sqrt(np.mean(self.residual**2)))


def _refit(task: tuple[Any, ...]) -> _Refit:
    """Refit ``effects`` locally from the calibrated point (a candidate starts switched off)."""
    spec, data, effects, effect, params, noise = task
    problem = CalibrationProblem(spec, data, effects)
    runs = _Runs(problem, spec.directory / ".solver-cache", jobs=1)
    fit = _local_fit(problem, runs, _start(problem, params), noise=noise)
    return _Refit(
        effect,
        fit.theta,
        dict(zip(problem.space.names, map(float, fit.theta), strict=True)),
        fit.residual,
        fit.curves,
        fit.heldout_rmse,
        runs.used,
    )


def _recalibrate(task: tuple[Any, ...]) -> tuple[_Refit | None, int]:
    """:func:`calibrate` with the effect added (not a ladder step), then refitted locally."""
    spec, data, effects, effect, noise = task
    try:
        found = calibrate(spec, effects=effects, progress=False, record=False)
        return _refit((spec, data, effects, effect, found.params, noise)), found.solver_calls
    except (InputDataError, _Failed):
        return None, 0  # the solver failed wherever the search looked: keep the local refit


def _named(best: dict[str, Any], heldout: float, noise: float | None = None) -> bool:
    """Decisive (ΔBIC < −10) and cuts the held-out error ≥ 10 %; with ``noise``: and
    brings the RMSE near it (nothing left to look for)."""
    decisive = (
        best["delta_bic"] < DECISIVE_DELTA_BIC and best["heldout_rmse_n"] < HELDOUT_GAIN * heldout
    )
    return decisive and (noise is None or best["rmse_n"] <= NEAR_NOISE * noise)


def _tied(entry: dict[str, Any], best: dict[str, Any]) -> bool:
    """Not decisively worse than the best (ΔBIC within 10 of it)."""
    return entry["delta_bic"] - best["delta_bic"] < -DECISIVE_DELTA_BIC


def _jobs(jobs: int | None, tasks: int) -> int:
    if jobs is not None and jobs < 1:
        raise InputDataError(f"jobs must be ≥ 1, got {jobs}")
    return max(1, min(jobs or os.cpu_count() or 1, tasks))


def _one_blas_thread() -> None:
    """Several processes each spinning a BLAS thread pool on the same cores run ~10× slower."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


def _map(function: Any, tasks: list[Any], jobs: int) -> Iterator[Any]:
    """``function`` over ``tasks`` in ``jobs`` forked processes, yielding as each finishes.

    Forked, so effects registered in this process (plug-ins, or in code) exist in
    the workers too.
    """
    if jobs == 1:
        yield from map(function, tasks)
        return
    if "fork" not in multiprocessing.get_all_start_methods():
        yield from map(function, tasks)  # no fork (Windows): plug-ins would be lost; serially
        return
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(
        max_workers=jobs, mp_context=context, initializer=_one_blas_thread
    ) as pool:
        futures = [pool.submit(function, task) for task in tasks]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _local_fit(
    problem: CalibrationProblem, runs: _Runs, theta: np.ndarray, *, noise: float
) -> _Fit:
    """The shared local phase from ``theta`` (looser tolerances, one round: a refit ranks
    candidates, it does not certify an optimum); LOO-test error of the linearised fit."""
    try:
        fit = local_fit(
            ResidualModel(problem, runs),
            theta,
            ftol=1e-4,
            xtol=1e-5,
            max_evaluations=_LOCAL_EVALS,
            jacobian_refresh=1,
            rounds=1,
        )
    except SolverFailed as failed:
        raise _Failed(str(failed)) from failed
    heldout = _heldout(problem, fit.residual, fit.jacobian, fit.at_bound, noise)
    return _Fit(fit.theta, fit.residual, fit.curves, heldout)


@dataclass
class _Fit:
    theta: np.ndarray
    residual: np.ndarray
    curves: np.ndarray
    heldout_rmse: float


class _Failed(Exception):
    pass


def _heldout(
    problem: CalibrationProblem,
    residual: np.ndarray,
    jac: np.ndarray,
    at_bound: np.ndarray,
    noise: float,
) -> float:
    """Leave-one-test-out RMSE of the linearised fit at the optimum.

    Each test in turn is left out and the linearised model refitted on the
    others — with a Gaussian prior of ``LOO_PRIOR_UNIT`` of each parameter's range
    around the full-data fit (ridge ``λ = noise²/σ²``), so a parameter only the
    left-out test determines (the weft factor of a lone weft test) stays where
    the full data put it instead of running off — then the left-out test is
    predicted. A parameter held at a bound of its range (``at_bound``: −1 lower,
    +1 upper, and the fit pushes against it) stays there: the linearisation knows
    no bounds.
    """
    gradient = jac.T @ residual
    # held at a bound: the fit pushes against it (descent direction −gradient points out)
    active = ((at_bound < 0) & (gradient > 0)) | ((at_bound > 0) & (gradient < 0))
    jac = jac[:, ~active]
    gradient = gradient[~active]
    ridge = (noise / LOO_PRIOR_UNIT) ** 2 * np.eye(jac.shape[1])
    gram = jac.T @ jac
    total = 0.0
    for index in range(len(problem.test_ids)):
        rows = problem.point_test == index
        j_t, r_t = jac[rows], residual[rows]
        step = np.linalg.solve(gram - j_t.T @ j_t + ridge, -(gradient - j_t.T @ r_t))
        left_out = r_t + j_t @ step
        total += float(left_out @ left_out)
    return math.sqrt(total / residual.size)


def _candidates(
    problem: CalibrationProblem, chosen: Sequence[str], names: Sequence[str] | None
) -> list[str]:
    """Effects to try: not in the model, and each condition they read varies in the data."""
    table = problem.data.tests
    out = []
    for name in names if names is not None else available_effects():
        if name in chosen:
            continue
        effect = get_effect(name)
        readable = [c for c in effect.reads if c in table and c != "width_mm"]
        if readable and all(table[c].nunique() < 2 for c in readable):
            continue  # nothing in the data can show it
        if any(c not in table for c in effect.reads if c not in ("width_mm",)):
            continue
        out.append(name)
    return out


def _start(problem: CalibrationProblem, params: dict[str, float]) -> np.ndarray:
    """The calibrated point with the new effect switched off (its nearest bound)."""
    values = []
    for spec in problem.space:
        if spec.name in params:
            values.append(params[spec.name])
            continue
        effect, name = spec.name.split(".", 1)
        off = next(p.off for p in get_effect(effect).parameters if p.name == name)
        if math.isnan(off):  # friction: start from the rig's own value
            off = problem.spec.rig.friction
        values.append(min(max(off, spec.low), spec.high))
    return np.array(values, dtype=float)


def _verdict(
    rmse: float,
    heldout: float,
    noise: float,
    systematic: bool,
    p_value: float,
    ranking: list[dict[str, Any]],
    follows: list[dict[str, Any]],
    tied: Sequence[str] = (),
) -> tuple[dict[str, Any] | None, str]:
    trail = [f for f in follows if f["significant"]]
    column = trail[0]["covariate"] if trail else None
    if not systematic:
        return None, (
            f"no systematic misfit: RMSE {rmse:.3g} N is what noise {noise:.3g} N explains "
            f"(p = {p_value:.2g}); no effect needed"
        )
    best = ranking[0] if ranking else None
    named = best is not None and _named(best, heldout)
    if named and best is not None:
        why = f"residual follows {column}; " if column else ""
        text = (
            f"missing effect: {best['effect']} — {why}`{best['effect']}` cuts held-out RMSE "
            f"from {heldout:.3g} N to {best['heldout_rmse_n']:.3g} N "
            f"(ΔBIC {best['delta_bic']:.0f}), noise {noise:.3g} N"
        )
        if tied:
            also = ", ".join(f"`{name}`" for name in tied)
            text += (
                f"; {also} {'fits' if len(tied) == 1 else 'fit'} as well (ΔBIC within "
                f"{-DECISIVE_DELTA_BIC:.0f}): these data cannot tell them apart"
            )
        if best["rmse_n"] <= NEAR_NOISE * noise:
            return None, text
        text += "; a misfit remains after it"
    if column is None:
        return {"covariate": None}, (
            f"unexplained: RMSE {rmse:.3g} N against noise {noise:.3g} N, and the residual "
            "follows no recorded column; no effect in the library explains it"
        )
    unexplained = {"covariate": column, "p_value": trail[0]["p_value"]}
    lead = text + ". " if named else ""
    return unexplained, (
        f"{lead}unexplained: residual follows {column}; no effect in the library explains "
        "it — write a plug-in effect"
    )


# -- the model ladder ---------------------------------------------------------------------------
def _record_heldout(url: str, name: str, heldout: float) -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        study = optuna.load_study(study_name=name, storage=url)
    except KeyError:
        return
    study.set_user_attr("heldout_rmse_n", heldout)


def model_ladder(url: str, name: str) -> list[dict[str, Any]]:
    """Every calibration of the study, as steps of the model ladder (fewest effects first)."""
    prefix = f"{name}/calibrate/"
    steps = []
    for summary in optuna.get_all_study_summaries(storage=url, include_best_trial=False):
        if not summary.study_name.startswith(prefix):
            continue
        result = summary.user_attrs.get("result")
        if not result:
            continue
        steps.append(
            {
                "model": summary.study_name[len(prefix) :],
                "effects": result["effects"],
                "rmse_n": result["rmse_n"],
                "heldout_rmse_n": summary.user_attrs.get("heldout_rmse_n"),
                "noise_n": result["noise_n"],
                "solver_calls": result["solver_calls"],
                "params": result["params"],
            }
        )
    return sorted(steps, key=lambda s: (len(s["effects"]), -s["rmse_n"]))


def write_ladder_plot(ladder: list[dict[str, Any]], path: Path) -> Path | None:
    """The falling error of the ladder as a PNG (None without matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    if not ladder:
        raise InputDataError("no calibration in the storage yet; run surrogate calibrate first")
    figure, axis = plt.subplots(figsize=(7, 4))
    x = np.arange(len(ladder))
    axis.plot(x, [s["rmse_n"] for s in ladder], "o-", label="RMSE")
    held = [s["heldout_rmse_n"] for s in ladder]
    if any(h is not None for h in held):
        axis.plot(x, [np.nan if h is None else h for h in held], "s--", label="held-out RMSE")
    axis.axhline(ladder[0]["noise_n"], color="grey", ls=":", label="noise")
    axis.set_yscale("log")
    axis.set_xticks(x, [s["model"] for s in ladder], rotation=20)
    axis.set(ylabel="error [N]", title="Model ladder: the error as effects are added")
    axis.legend()
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
