"""``compare``: measured against model curves, test by test, where the model fails.

For the calibrated (or given) parameters, every test is simulated with the full
solver at its own conditions (through the result cache). Residuals
(measured − model) are summarised per test, per angle band and against every
condition and covariate, and set against the noise level. Angle bands come
from each test's model curve: the *elastic rise* below ``θsat − 10°``, the
*transition* within ±10° of θsat, the *plateau* above ``θsat + 10°`` (a curve
that never saturates has no plateau).

Plots (PNG): the curves overlaid, the residual against angle, and each test's
mean residual against each condition and covariate; the same figures are
attached to the calibration's study for optuna-dashboard.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna

from .._errors import InputDataError, SolverError
from .._io import check_output_folder
from .._log import show_progress
from .._pool import one_blas_thread_within
from ..physics import curve_features
from ..storage._optuna import quiet_optuna
from ..storage._storage import (
    check_storage_url,
    missing_local_storage,
    open_storage,
    refuse_in_memory,
)
from ._calibrate import beaten_by, beaten_text, calibration_note
from ._loop import SolverRuns
from ._problem import CalibrationProblem, calibration_study_name, load_calibration, model_label
from ._statistics import column_values

__all__ = [
    "BANDS",
    "CompareResult",
    "Comparison",
    "angle_bands",
    "compare",
    "comparison",
    "comparison_figures",
    "latest_calibration",
]

BAND_HALF_WIDTH_DEG = 10.0
BANDS = ("elastic rise", "transition", "plateau")

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class CompareResult:
    """Keys of ``surrogate compare --json``.

    ``tests``: per test its conditions and covariates, RMSE and mean residual
    (bias) [N]; ``bands``: RMSE per angle band; ``covariates``: for each
    condition or covariate that varies between tests, the correlation of the
    tests' mean residual with it; ``plots``: the PNG files written.
    ``calibration``: for the stored calibration (no ``params`` given), its
    ``status``, ``misfit`` and ``determination`` (see :class:`CalibrationResult`), and
    ``beaten_by``: a verified point of the same model and data in its study that fits
    better (another basin, e.g. an earlier run's: ``{trial, rmse_n, params}``; None where
    none does — the message then says so in one line); ``None`` for given parameters.

    ``params`` and ``effects`` are the model compared; ``rmse_n`` its RMSE over every
    measured point, ``noise_n`` the noise level and ``rmse_over_noise`` their ratio;
    ``study`` the calibration study the figures are attached to; ``message`` the summary
    line the command prints.
    """

    params: dict[str, float]
    effects: list[str]
    rmse_n: float
    noise_n: float
    rmse_over_noise: float
    tests: list[dict[str, Any]]
    bands: list[dict[str, Any]]
    covariates: dict[str, float]
    plots: list[str]
    calibration: dict[str, Any] | None
    study: str
    message: str

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def latest_calibration(
    storage: str | optuna.storages.BaseStorage, name: str
) -> dict[str, Any] | None:
    """The stored result of the calibration study ``name`` in ``storage`` (a URL or an
    opened storage), if any."""
    if isinstance(storage, str):
        if missing_local_storage(storage) is not None:  # none yet: nothing is created
            return None
        storage = open_storage(storage)
    try:
        study = optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        return None
    return study.user_attrs.get("result")


@dataclass(frozen=True)
class Comparison:
    """What :func:`compare` computes before it plots and records anything.

    ``curves`` are the model's curves (G, A) on the problem's whole degrees, one per
    condition group; ``residual`` is measured − model at every measured point;
    ``stored`` the calibration record the parameters came from (None for given
    parameters); ``storage`` the storage URL; ``result`` the record (no plots yet).
    """

    problem: CalibrationProblem
    curves: np.ndarray
    residual: np.ndarray
    stored: dict[str, Any] | None
    storage: str
    result: CompareResult


@one_blas_thread_within
def compare(
    study: Any,
    *,
    params: Mapping[str, float] | None = None,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    output_dir: str | Path | None = None,
    plots: bool = True,
    progress: bool = True,
) -> CompareResult:
    """Measured vs model curves for the calibrated (or given) parameters.

    Parameters
    ----------
    study : path or StudySpec
        A study with a ``[measurements]`` file.
    params : mapping, optional
        Parameter values (coating, ``effect.param``); default: the last
        calibration of this model in the study's storage.
    effects : sequence of str, optional
        The model's effects; default: the study's ``[model] effects``.
    output_dir : path, optional
        Folder of the PNG plots; default ``<study folder>/<name>-compare``.
    progress : bool
        Log the summary at INFO (logger ``surrogate``; on stderr unless configured).
    """
    if progress:
        show_progress()
    if plots and output_dir is not None:
        check_output_folder(output_dir)
    found = comparison(study, params=params, effects=effects, plugins=plugins, storage=storage)
    result, problem = found.result, found.problem
    if plots:
        spec = problem.spec
        folder = Path(output_dir) if output_dir else spec.directory / f"{spec.name}-compare"
        files = _plots(problem, found.curves, found.residual, result.tests, folder, result.effects)
        result = replace(result, plots=files)
    _attach(found, result)
    if progress:
        _LOG.info("[%s] %s", result.study, result.message)
    return result


def comparison(
    study: Any,
    *,
    params: Mapping[str, float] | None = None,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    solve: bool = True,
) -> Comparison:
    """The comparison of :func:`compare` (same arguments), without plots, without
    writing to the storage and without logging. ``solve=False`` takes the model curves
    from the result cache only and refuses (InputDataError) when a run is not there
    (a reader that must not start an hour-long external solver run)."""
    spec, data, chosen, noise = load_calibration(study, effects, plugins)
    problem = CalibrationProblem(spec, data, chosen)
    url = storage or spec.default_storage()
    check_storage_url(url)  # before the work
    if params is None:  # before the storage is opened: a new in-memory one holds nothing
        refuse_in_memory(url, "`compare` without --params")
    name = calibration_study_name(spec, chosen)
    stored = None if params is not None else latest_calibration(url, name)
    beaten = None if stored is None else beaten_by(url, name, stored)
    theta = _parameters(problem, params if stored is None else stored["params"], url, name)
    curves = _model_curves(problem, theta, solve=solve)
    residual = problem.residuals(curves)
    tests = _per_test(problem, residual)
    rmse = float(np.sqrt(np.mean(residual**2)))
    bands = _band_table(problem, curves, residual)
    result = CompareResult(
        params=dict(zip(problem.space.names, map(float, theta), strict=True)),
        effects=list(chosen),
        rmse_n=rmse,
        noise_n=noise,
        rmse_over_noise=rmse / noise,
        tests=tests,
        bands=bands,
        covariates=_covariate_correlations(problem, tests),
        plots=[],
        calibration=None if stored is None else {**_claims(stored), "beaten_by": beaten},
        study=name,
        message=_message(chosen, rmse, noise, tests, bands, stored)
        + ("" if beaten is None else "; " + beaten_text(model_label(chosen), beaten, noise)),
    )
    return Comparison(problem, curves, residual, stored, url, result)


def _model_curves(problem: CalibrationProblem, theta: np.ndarray, *, solve: bool) -> np.ndarray:
    """The full solver's curves (G, A) at ``theta`` for every condition group (``solve``
    False: from the result cache only)."""
    runs = SolverRuns(problem, problem.spec.directory / ".solver-cache", jobs=1)
    thetas, groups = problem.at_every_group(theta)
    absent = [] if solve else [k for k in runs.keys(thetas, groups) if k not in runs.cache]
    if absent:
        raise InputDataError(
            f"{len(absent)} of its {len(thetas)} full-solver runs ({problem.spec.solver}) "
            f"are not in the result cache {runs.cache.directory}; "
            "make them with `surrogate compare`"
        )
    out = runs.run(thetas, groups)
    done = [o for o in out if o is not None]
    if len(done) < len(out):
        raise SolverError(
            f"the full solver failed at these parameters ({runs.failures[0]}); "
            "compare needs a curve for every test"
        )
    return np.array([o.curve for o in done])


def _band_table(
    problem: CalibrationProblem, curves: np.ndarray, residual: np.ndarray
) -> list[dict[str, Any]]:
    """RMSE, bias and points of every angle band that has points."""
    band = angle_bands(problem, curves)
    return [
        {
            "band": label,
            "rmse_n": float(np.sqrt(np.mean(residual[band == i] ** 2))),
            "bias_n": float(np.mean(residual[band == i])),
            "points": int(np.sum(band == i)),
        }
        for i, label in enumerate(BANDS)
        if np.any(band == i)
    ]


def _message(
    effects: Sequence[str],
    rmse: float,
    noise: float,
    tests: list[dict[str, Any]],
    bands: list[dict[str, Any]],
    stored: Mapping[str, Any] | None,
) -> str:
    worst = max(tests, key=lambda t: t["rmse_n"])
    return (
        f"{model_label(effects)}: RMSE {rmse:.4g} N = {rmse / noise:.2f}× noise ({noise:.3g} N); "
        f"worst test {worst['test_id']} ({worst['rmse_n']:.3g} N); "
        + ", ".join(f"{b['band']} {b['rmse_n']:.3g} N" for b in bands)
        + _calibration_summary(stored)
    )


def _claims(stored: Mapping[str, Any]) -> dict[str, Any]:
    """What the stored calibration claims."""
    return {k: stored.get(k) for k in ("status", "misfit", "misfit_p_value", "determination")}


def _calibration_summary(stored: Mapping[str, Any] | None) -> str:
    """What the stored calibration claims: its status, misfit and what the curves determine."""
    if stored is None:
        return ""
    misfit = (
        f"{stored['misfit']} (p = {stored['misfit_p_value']:.2g})" if stored.get("misfit") else ""
    )
    if stored.get("status") != "converged" or not stored.get("determination"):
        fits = f", its misfit {misfit}" if misfit else ""
        return f"; calibration {stored.get('status')}: not at a verified local optimum{fits}"
    return f"; calibration converged, {misfit}; {stored['determination']['statement']}"


def _parameters(
    problem: CalibrationProblem, params: Mapping[str, float] | None, url: str, name: str
) -> np.ndarray:
    names = problem.space.names
    if params is None:
        raise InputDataError(
            f"no calibration of model {name!r} in {url}; run `surrogate calibrate` "
            "first or give --params"
        )
    unknown = [k for k in params if k not in names]
    missing = [k for k in names if k not in params]
    if unknown or missing:
        raise InputDataError(
            f"--params must give exactly {', '.join(names)}; "
            + (f"unknown {', '.join(unknown)}" if unknown else f"missing {', '.join(missing)}")
        )
    values = np.array([float(params[k]) for k in names])
    for spec, value in zip(problem.space, values, strict=True):
        if not np.isfinite(value) or not (spec.low <= value <= spec.high):
            raise InputDataError(
                f"--params {spec.name}={value:g} is outside its range [{spec.low:g}, {spec.high:g}]"
            )
    return values


def _per_test(problem: CalibrationProblem, residual: np.ndarray) -> list[dict[str, Any]]:
    rows = []
    table = problem.data.tests.set_index("test_id")
    extra = [*problem.data.conditions, *problem.data.covariates]
    for index, test_id in enumerate(problem.test_ids):
        r = residual[problem.point_test == index]
        row: dict[str, Any] = {
            "test_id": str(test_id),
            "rmse_n": float(np.sqrt(np.mean(r**2))),
            "bias_n": float(np.mean(r)),
        }
        for column in extra:
            value = table.loc[test_id, column]
            row[column] = value if isinstance(value, str) else float(value)
        rows.append(row)
    return rows


def angle_bands(problem: CalibrationProblem, curves: np.ndarray) -> np.ndarray:
    """Band index (0 rise, 1 transition, 2 plateau) of every measured point."""
    theta_sat = np.array(
        [
            curve_features(problem.angle_deg, c).theta_sat_deg
            if curve_features(problem.angle_deg, c).saturated
            else np.inf
            for c in curves
        ]
    )
    at = theta_sat[problem.point_group]
    angle = problem.point_angle_deg
    band = np.ones(angle.size, dtype=int)
    band[angle < at - BAND_HALF_WIDTH_DEG] = 0
    band[angle > at + BAND_HALF_WIDTH_DEG] = 2
    return band


def _covariate_correlations(
    problem: CalibrationProblem, tests: list[dict[str, Any]]
) -> dict[str, float]:
    bias = np.array([t["bias_n"] for t in tests])
    out = {}
    for column in (*problem.data.conditions, *problem.data.covariates):
        x = column_values([t[column] for t in tests])
        if x is None or np.ptp(x) == 0 or np.ptp(bias) == 0:
            continue
        out[column] = float(np.corrcoef(x, bias)[0, 1])
    return out


def _plots(
    problem: CalibrationProblem,
    curves: np.ndarray,
    residual: np.ndarray,
    tests: list[dict[str, Any]],
    folder: Path,
    effects: Sequence[str],
) -> list[str]:
    """The PNG figures in ``folder`` (none, with a warning, without matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as error:  # optional: pip install .[plots]
        warnings.warn(f"PNG plots skipped ({error.name} is not installed)", stacklevel=3)
        return []
    folder.mkdir(parents=True, exist_ok=True)
    label = model_label(effects)
    files = [
        _save(_curves_png(plt, problem, curves, label), folder / f"curves-{label}.png"),
        _save(_residual_png(plt, problem, residual, label), folder / f"residual-angle-{label}.png"),
    ]
    if [*problem.data.conditions, *problem.data.covariates]:
        figure = _covariates_png(plt, problem, tests, label)
        files.append(_save(figure, folder / f"residual-covariates-{label}.png"))
    return files


def _curves_png(plt: Any, problem: CalibrationProblem, curves: np.ndarray, label: str) -> Any:
    """Measured points and model curves of every test."""
    colours = plt.get_cmap("tab10")
    figure, axis = plt.subplots(figsize=(8, 5.5))
    for index, test_id in enumerate(problem.test_ids):
        mask = problem.point_test == index
        colour = colours(index % 10)
        axis.plot(problem.point_angle_deg[mask], problem.measured_n[mask], ".", ms=2, color=colour)
        axis.plot(
            problem.angle_deg,
            curves[problem.test_group[index]],
            "-",
            color=colour,
            lw=1.2,
            label=str(test_id),
        )
    axis.set(
        xlabel="fixture rotation [deg]",
        ylabel="probe force [N]",
        title=f"Measured (dots) and model (lines), model: {label}",
    )
    axis.legend(fontsize=7, ncol=2)
    return figure


def _residual_png(plt: Any, problem: CalibrationProblem, residual: np.ndarray, label: str) -> Any:
    """The residual of every test against the angle."""
    colours = plt.get_cmap("tab10")
    figure, axis = plt.subplots(figsize=(8, 4.5))
    for index, test_id in enumerate(problem.test_ids):
        mask = problem.point_test == index
        axis.plot(
            problem.point_angle_deg[mask],
            residual[mask],
            "-",
            lw=0.8,
            color=colours(index % 10),
            label=str(test_id),
        )
    rmse = float(np.sqrt(np.mean(residual**2)))
    axis.axhline(0.0, color="black", lw=0.8)
    axis.set(
        xlabel="fixture rotation [deg]",
        ylabel="measured − model [N]",
        title=f"Residual against angle, model: {label} (RMSE {rmse:.3g} N)",
    )
    axis.legend(fontsize=7, ncol=2)
    return figure


def _covariates_png(
    plt: Any, problem: CalibrationProblem, tests: list[dict[str, Any]], label: str
) -> Any:
    """Each test's mean residual (± its RMSE) against each condition and covariate."""
    columns = [*problem.data.conditions, *problem.data.covariates]
    figure, axes = plt.subplots(1, len(columns), figsize=(3.2 * len(columns), 3.4))
    axes = np.atleast_1d(axes)
    bias = [t["bias_n"] for t in tests]
    rms = [t["rmse_n"] for t in tests]
    for axis, column in zip(axes, columns, strict=True):
        values = [t[column] for t in tests]
        axis.errorbar(values, bias, yerr=rms, fmt="o", ms=4, capsize=2)
        if column == "rate_deg_s":
            axis.set_xscale("log")
        axis.axhline(0.0, color="black", lw=0.8)
        axis.set(xlabel=column, ylabel="mean residual ± RMSE [N]")
    figure.suptitle(f"Residual per test against conditions and covariates ({label})")
    return figure


def _save(figure: Any, path: Path) -> str:
    import matplotlib.pyplot as plt

    figure.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    figure.savefig(tmp, dpi=110)
    plt.close(figure)
    tmp.replace(path)
    return str(path)


def _attach(found: Comparison, result: CompareResult) -> None:
    """The same figures as plotly objects on the calibration study (optuna-dashboard);
    the note keeps the calibration's own statement above the comparison."""
    try:
        from optuna_dashboard import save_note, save_plotly_graph_object

        figures = comparison_figures(found)
    except ImportError:
        return
    quiet_optuna()
    study = optuna.create_study(
        study_name=result.study, storage=open_storage(found.storage), load_if_exists=True
    )
    for graph_id, figure in figures.items():
        save_plotly_graph_object(study, figure, graph_object_id=graph_id)
    save_note(study, "\n".join(_note_lines(result.tests, result, found.stored)))


def comparison_figures(found: Comparison) -> dict[str, Any]:
    """Plotly figures of a comparison by id: the measured and model curves, the residual
    against the angle, and (when the tests record any) the tests' mean residual against
    each condition and covariate. Raises ImportError without plotly."""
    import plotly.graph_objects as go

    problem = found.problem
    figures = {
        "compare-curves": _curves_plotly(go, problem, found.curves),
        "compare-residual-angle": _residual_plotly(go, problem, found.residual),
    }
    columns = [*problem.data.conditions, *problem.data.covariates]
    if columns:
        figures["compare-residual-covariates"] = _covariates_plotly(go, columns, found.result.tests)
    return figures


def _curves_plotly(go: Any, problem: CalibrationProblem, curves: np.ndarray) -> Any:
    figure = go.Figure()
    for index, test_id in enumerate(problem.test_ids):
        mask = problem.point_test == index
        figure.add_trace(
            go.Scatter(
                x=problem.point_angle_deg[mask],
                y=problem.measured_n[mask],
                mode="markers",
                marker={"size": 3},
                name=f"{test_id} measured",
                legendgroup=str(test_id),
            )
        )
        figure.add_trace(
            go.Scatter(
                x=problem.angle_deg,
                y=curves[problem.test_group[index]],
                mode="lines",
                name=f"{test_id} model",
                legendgroup=str(test_id),
            )
        )
    figure.update_layout(
        title="Measured and model curves",
        xaxis_title="fixture rotation [deg]",
        yaxis_title="probe force [N]",
    )
    return figure


def _residual_plotly(go: Any, problem: CalibrationProblem, residual: np.ndarray) -> Any:
    figure = go.Figure()
    for index, test_id in enumerate(problem.test_ids):
        mask = problem.point_test == index
        figure.add_trace(
            go.Scatter(
                x=problem.point_angle_deg[mask], y=residual[mask], mode="lines", name=str(test_id)
            )
        )
    figure.update_layout(
        title="Residual (measured − model) against angle",
        xaxis_title="fixture rotation [deg]",
        yaxis_title="residual [N]",
    )
    return figure


def _covariates_plotly(go: Any, columns: Sequence[str], tests: list[dict[str, Any]]) -> Any:
    figure = go.Figure()
    for column in columns:
        figure.add_trace(
            go.Scatter(
                x=[t[column] for t in tests],
                y=[t["bias_n"] for t in tests],
                mode="markers",
                name=column,
                text=[t["test_id"] for t in tests],
            )
        )
    figure.update_layout(
        title="Mean residual per test against each condition and covariate",
        yaxis_title="mean residual [N]",
    )
    return figure


def _note_lines(
    tests: list[dict[str, Any]], result: CompareResult, stored: Mapping[str, Any] | None
) -> list[str]:
    """The dashboard note: the calibration's statement (if stored), then the comparison."""
    lines = [
        f"## Compare: {result.message}",
        "",
        "| test | RMSE [N] | bias [N] |",
        "|---|---|---|",
        *[f"| {t['test_id']} | {t['rmse_n']:.4g} | {t['bias_n']:+.4g} |" for t in tests],
        "",
        "| band | RMSE [N] | points |",
        "|---|---|---|",
        *[f"| {b['band']} | {b['rmse_n']:.4g} | {b['points']} |" for b in result.bands],
    ]
    if stored is not None:
        lines = [*calibration_note(stored), "", *lines]
    return lines
