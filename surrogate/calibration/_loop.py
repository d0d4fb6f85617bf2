"""``calibrate``: fit the coating and the enabled effects to measured curves.

The machinery of the main loop, over parameters × test conditions:

1. every test is simulated at its own conditions; tests whose conditions the
   model cannot tell apart (replicates, or a ``direction`` no enabled effect
   reads) share one solver run per parameter point — a *condition group*;
2. an initial Latin hypercube over the parameters, each point run at one
   condition group in turn (a run at every group would cost G times more);
3. a GP surrogate of the whole curve over parameters × conditions
   (:class:`CurveSurrogate`), an Optuna TPE search of the predicted RMSE,
   polished by L-BFGS-B on the surrogate;
4. the candidate is verified with the full solver at every condition group
   (a trial of the study ``<name>/calibrate/<model>``, value: the RMSE over all
   measured points), its runs join the training set, and the loop repeats
   until a verification no longer improves on the best one and agrees with
   its prediction, or the budget is spent.

Misfit: RMSE over all measured points, and per test. The model curve is the
solver's on whole degrees, interpolated to the measured angles.
"""

from __future__ import annotations

import hashlib
import json
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from scipy.optimize import minimize
from scipy.stats import qmc
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from .._errors import InputDataError
from ..effects import ModelState, get_effect, load_plugin
from ..physics import bending_stiffness, plastic_moment
from ..solvers._batch import solve_inputs, solver_inputs
from ..solvers._cache import ResultCache, input_hash
from ..solvers._simulate import model_state_of
from ..study._conditions import CONDITIONS
from ..study._measurements import MeasurementSet, load_measurements
from ..study._space import ParameterSpace, ParameterSpec
from ..study._spec import StudySpec, load_study
from ..study._units import gpa_to_mpa
from ._determination import determine
from ._local import (
    FIRST_ORDER_BOX,
    BudgetSpent,
    LocalFit,
    ResidualModel,
    SolverFailed,
    local_fit,
)
from ._statistics import SIGNIFICANCE, misfit_p_value, noise_dof

__all__ = [
    "CalibrationProblem",
    "CalibrationResult",
    "CurveSurrogate",
    "calibrate",
    "calibration_study_name",
    "coat_section",
    "model_label",
]

RIG_CONDITIONS = ("tension_n", "bending_length_mm", "width_mm")
FORCE_SCALE_N = 0.02  # asinh(F/s): logarithmic above ~s, linear through 0
DEFAULT_CALIBRATION_CALLS = 200
_SEARCH_BATCH = 25
SETTLED = 0.01  # relative RMSE improvement below which the global phase has settled
STALE_LIMIT = 2  # the local phase finishes what the global one leaves
BASIN_CHECKS = 3  # local fits at most: the first basin and up to two others the surrogate shows
VALLEY_P = 0.05  # a misfit this unlikely under the noise alone: look along the valley
VALLEY_RMSE = 1.5  # …if within this many times the noise (beyond, the model is at fault)
VALLEY_STEP = 0.25  # the valley starts: a quarter of a range along the least determined direction


# -- the problem: parameters, condition groups, measured points ------------------------------
def model_label(effects: Sequence[str]) -> str:
    """A model's name: ``base`` or its effects joined by ``+`` (sorted)."""
    return "+".join(sorted(effects)) if effects else "base"


def calibration_study_name(spec: StudySpec, effects: Sequence[str]) -> str:
    return f"{spec.name}/calibrate/{model_label(effects)}"


class CalibrationProblem:
    """Parameters, condition groups and measured points of one calibration.

    Parameters
    ----------
    spec : StudySpec
        The study (coating ranges, rig, solver).
    data : MeasurementSet
        The measured curves.
    effects : sequence of str
        Enabled effects; their parameters are calibrated as ``effect.param``.
    tests : sequence, optional
        Use only these tests (the diagnosis leaves one out).
    """

    def __init__(
        self,
        spec: StudySpec,
        data: MeasurementSet,
        effects: Sequence[str] = (),
        *,
        tests: Sequence[Any] | None = None,
    ) -> None:
        self.spec = spec
        self.data = data
        self.effects = tuple(sorted(set(effects)))
        specs = list(spec.space.parameters)
        reads: set[str] = set(RIG_CONDITIONS)
        for name in self.effects:
            effect = get_effect(name)
            reads.update(effect.reads)
            for p in effect.parameters:
                specs.append(
                    ParameterSpec(f"{name}.{p.name}", p.low, p.high, log=p.log, unit=p.unit)
                )
        self.space = ParameterSpace.of(specs)
        self.conditions = tuple(
            c for c in (*CONDITIONS, *data.covariates) if c in reads and c in data.tests
        )
        test_ids = list(data.tests.test_id) if tests is None else list(tests)
        self.test_ids = test_ids
        self.groups: list[dict[str, Any]] = []
        group_of: dict[tuple[Any, ...], int] = {}
        self.test_group: list[int] = []
        table = data.tests.set_index("test_id")
        for test_id in test_ids:
            row = table.loc[test_id]
            conditions = {
                c: row[c] if isinstance(row[c], str) else float(row[c]) for c in self.conditions
            }
            key = tuple(conditions[c] for c in self.conditions)
            if key not in group_of:
                group_of[key] = len(self.groups)
                self.groups.append(conditions)
            self.test_group.append(group_of[key])
        self.angle_deg = np.arange(0.0, np.floor(spec.rig.max_angle_deg) + 1.0)
        self._points(data, test_ids)

    def _points(self, data: MeasurementSet, test_ids: list[Any]) -> None:
        angles, forces, group, test = [], [], [], []
        for index, test_id in enumerate(test_ids):
            a, f = data.curve(test_id)
            if a.max() > self.angle_deg[-1] or a.min() < 0.0:
                raise InputDataError(
                    f"test {test_id!r} has angles outside 0–{self.angle_deg[-1]:g}°, "
                    "the rig's range; raise [rig] max_angle_deg or drop those rows"
                )
            angles.append(a)
            forces.append(f)
            group.append(np.full(a.size, self.test_group[index]))
            test.append(np.full(a.size, index))
        angle = np.concatenate(angles)
        self.measured_n = np.concatenate(forces)
        self.point_group = np.concatenate(group)
        self.point_test = np.concatenate(test)
        self._lo = np.minimum(np.floor(angle).astype(int), self.angle_deg.size - 2)
        self._w = angle - self._lo
        self.point_angle_deg = angle
        self._count = np.bincount(self.point_test, minlength=len(test_ids))

    @property
    def n_points(self) -> int:
        return int(self.measured_n.size)

    # -- parameters ----------------------------------------------------------------------------
    def split(self, theta: Mapping[str, float]) -> tuple[dict[str, float], dict[str, Any]]:
        """Coating point and effects mapping of a parameter vector."""
        coating = {n: float(theta[n]) for n in self.spec.space.names}
        effects: dict[str, dict[str, float]] = {name: {} for name in self.effects}
        for name in self.space.names:
            if "." in name:
                effect, param = name.split(".", 1)
                effects[effect][param] = float(theta[name])
        return coating, effects

    def state(self, theta: np.ndarray, group: int) -> ModelState:
        """The model state the solver sees for parameter vector ``theta`` at a group."""
        coating, effects = self.split(dict(zip(self.space.names, theta, strict=True)))
        return model_state_of(
            coating["ecoat_gpa"],
            coating["scoat_gpa"],
            coating["tcoat_mm"],
            self.spec.rig,
            effects,
            self.groups[group],
        )

    def inputs(self, theta: Mapping[str, float], group: int) -> dict[str, Any]:
        coating, effects = self.split(theta)
        return solver_inputs(
            coating,
            self.spec.rig,
            solver=self.spec.solver,
            effects=effects,
            conditions=self.groups[group],
            solver_settings=self.spec.solver_settings,
        )

    # -- misfit --------------------------------------------------------------------------------
    def model_at_points(self, curves: np.ndarray) -> np.ndarray:
        """Model force at every measured point from (G, A) curves on whole degrees."""
        c = curves[self.point_group]
        rows = np.arange(self.point_group.size)
        return c[rows, self._lo] * (1.0 - self._w) + c[rows, self._lo + 1] * self._w

    def residuals(self, curves: np.ndarray) -> np.ndarray:
        """Measured minus model at every measured point."""
        return self.measured_n - self.model_at_points(curves)

    def rmse(self, curves: np.ndarray) -> float:
        return float(np.sqrt(np.mean(self.residuals(curves) ** 2)))

    def rmse_per_test(self, curves: np.ndarray) -> dict[str, float]:
        r2 = np.bincount(self.point_test, self.residuals(curves) ** 2, len(self.test_ids))
        rms = np.sqrt(r2 / self._count)
        return {str(t): float(v) for t, v in zip(self.test_ids, rms, strict=True)}

    def _batch_points(self, curves: np.ndarray) -> np.ndarray:
        rows = np.arange(self.point_group.size)
        c = curves[:, self.point_group]  # (m, P, A)
        return c[:, rows, self._lo] * (1.0 - self._w) + c[:, rows, self._lo + 1] * self._w

    def batch_rmse(self, curves: np.ndarray) -> np.ndarray:
        """RMSE of each of (m, G, A) curve sets."""
        residual = self.measured_n - self._batch_points(curves)
        return np.sqrt(np.mean(residual**2, axis=1))


# -- the surrogate over parameters × conditions --------------------------------------------------
def state_features(state: ModelState) -> np.ndarray:
    """What the solver sees, as surrogate inputs (physical, dimensionless where it helps).

    Every effect acts through the model state of a test (design.md §4), so a
    surrogate over the state serves every model and every test condition: the
    tension effect's ``Ecoat·(1 + kE·T)`` is just another stiffness to it.
    Features: log of the total bending stiffness, of the plastic moment, of the
    yield strain and of Tcoat; the hardening ratio; the bare webbing's share of
    the stiffness; the probe friction; the self-weight over the strip's
    stiffness (``q·L³/(D·b)``); the strip's stiffness over the clamp's
    (``D·b/(l·k)``); the end tension over the elastic force scale
    (``T·l²/(D·b)``); the bending length and the width.
    """
    rig = state.rig
    coat = bending_stiffness(state.ecoat_mpa, state.tcoat_mm, rig.thickness_mm)
    total = coat + state.extra_stiffness_nmm
    plastic = plastic_moment(state.scoat_mpa, state.tcoat_mm, rig.thickness_mm)
    flexural = total * rig.width_mm  # D·b [N·mm²]
    clamp = (
        0.0
        if state.clamp_stiffness_nmm is None
        else flexural / rig.bending_length_mm / state.clamp_stiffness_nmm
    )
    return np.array(
        [
            np.log(total),
            np.log(plastic),
            np.log(state.scoat_mpa / state.ecoat_mpa),
            np.log(state.tcoat_mm),
            state.hardening_ratio,
            state.extra_stiffness_nmm / total,
            rig.friction,
            state.line_load_n_mm * rig.free_length_mm**3 / flexural,
            clamp,
            rig.tension_n * rig.bending_length_mm**2 / flexural,
            np.log(rig.bending_length_mm),
            np.log(rig.width_mm),
        ]
    )


class CurveSurrogate:
    """GP of the force curve over the model state of a test (see :func:`state_features`).

    The curve is transformed by ``asinh(F/s)`` (logarithmic for forces well
    above ``s`` = 0.02 N, linear through zero where a strip under self-weight
    has not yet touched the probe), reduced to principal components (99.9999 %
    of the variance, at most 16), one GP per score (Matérn ν = 2.5, ARD, with
    the coating features of :class:`~surrogate.gp.FeatureMap`). Hyperparameters
    are warm-started from the previous fit of the loop.
    """

    def __init__(self, problem: CalibrationProblem, *, seed: int = 0) -> None:
        self.problem = problem
        self.seed = seed
        self._kernels: list[Any] = []
        self._scale: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _inputs(self, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
        raw = np.array(
            [
                state_features(self.problem.state(x, int(g)))
                for x, g in zip(np.atleast_2d(X), groups, strict=True)
            ]
        )
        if self._scale is None:  # fixed at the first fit: warm-started kernels stay valid
            low, high = raw.min(axis=0), raw.max(axis=0)
            keep = high - low > 1e-12 * np.maximum(1.0, np.abs(high))
            self._scale = (keep, low, high)
        keep, low, high = self._scale
        return (raw[:, keep] - low[keep]) / (high[keep] - low[keep])

    def fit(self, X: np.ndarray, groups: np.ndarray, curves: np.ndarray) -> CurveSurrogate:
        Z = self._inputs(X, groups)
        Y = np.arcsinh(curves[:, 1:] / FORCE_SCALE_N)
        self.mean_ = Y.mean(axis=0)
        _, singular, basis = np.linalg.svd(Y - self.mean_, full_matrices=False)
        explained = np.cumsum(singular**2) / max(float(np.sum(singular**2)), 1e-300)
        k = int(min(np.searchsorted(explained, 1.0 - 1e-6) + 1, basis.shape[0], 16))
        self.basis_ = basis[:k]
        scores = (Y - self.mean_) @ self.basis_.T
        # universal kriging: a linear trend in the features (ridge-stabilised), GPs on the rest
        design = np.hstack([np.ones((Z.shape[0], 1)), Z])
        ridge = 1e-6 * np.eye(design.shape[1])
        ridge[0, 0] = 0.0
        self.trend_ = np.linalg.solve(design.T @ design + ridge, design.T @ scores)
        scores = scores - design @ self.trend_
        self.gps_ = []
        kernels = []
        for j in range(k):
            kernel = self._kernels[j] if j < len(self._kernels) else self._kernel(Z.shape[1])
            gp = GaussianProcessRegressor(
                kernel=kernel,
                normalize_y=True,
                n_restarts_optimizer=0 if j < len(self._kernels) else 1,
                random_state=self.seed,
            )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                gp.fit(Z, scores[:, j])
            self.gps_.append(gp)
            kernels.append(gp.kernel_)
        self._kernels = kernels
        return self

    @staticmethod
    def _kernel(n_features: int) -> Any:
        length = np.full(n_features, 0.5)
        return ConstantKernel(1.0, (1e-3, 1e3)) * Matern(
            length_scale=length, length_scale_bounds=(1e-2, 1e3), nu=2.5
        ) + WhiteKernel(1e-6, (1e-10, 1e-2))

    def predict(
        self, X: np.ndarray, return_std: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Curves (m, G, A) of every parameter point at every condition group.

        With ``return_std``, also their standard deviation [N] (the scores'
        GPs taken as independent, mapped through the transform's slope).
        """
        X = np.atleast_2d(X)
        m, G = X.shape[0], len(self.problem.groups)
        Z = self._inputs(np.repeat(X, G, axis=0), np.tile(np.arange(G), m))
        trend = np.hstack([np.ones((Z.shape[0], 1)), Z]) @ self.trend_
        if return_std:
            pairs = [gp.predict(Z, return_std=True) for gp in self.gps_]
            scores = trend + np.column_stack([p[0] for p in pairs])
            score_var = np.column_stack([p[1] ** 2 for p in pairs])
        else:  # the posterior mean without scikit-learn's per-call checks (the search's hot path)
            scores = trend + np.column_stack(
                [
                    gp._y_train_mean + gp._y_train_std * (gp.kernel_(Z, gp.X_train_) @ gp.alpha_)
                    for gp in self.gps_
                ]
            )
        Y = self.mean_ + scores @ self.basis_
        curves = np.zeros((m * G, Y.shape[1] + 1))
        curves[:, 1:] = FORCE_SCALE_N * np.sinh(Y)
        if not return_std:
            return curves.reshape(m, G, -1)
        std = np.zeros_like(curves)
        std[:, 1:] = FORCE_SCALE_N * np.cosh(Y) * np.sqrt(score_var @ self.basis_**2)
        return curves.reshape(m, G, -1), std.reshape(m, G, -1)


# -- the result --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationResult:
    """Keys of ``surrogate calibrate --json``.

    ``params`` are the calibrated values (coating in the paper's units, effect
    parameters as ``effect.param``); ``rmse_n`` the RMSE over all measured
    points, verified by the full solver; ``solver_calls`` the full-solver runs
    this calibration used (a run already in the result cache is not repeated).

    ``status`` is ``converged`` only when the local phase's first-order test held
    at ``params`` (a verified point; see :mod:`surrogate.calibration._local`), else
    ``budget_exhausted`` (``params`` is then the best verified point).
    ``predicted_gain`` is what that test measured: the relative RMSE decrease the
    Gauss–Newton model still promises within ±5 % of each range (``None`` unless
    ``converged``). With
    ``converged``: ``misfit`` is ``"within the noise"`` or ``"systematic"`` by the
    F-test of the RSS against the noise (``misfit_p_value``; systematic below
    0.01), and ``determination`` says what the curves determine (the keys of
    :class:`~surrogate.calibration._determination.Determination`: 95 % intervals of the
    bending stiffness ``bending_stiffness_nmm`` [N·mm per unit width], the plastic
    moment ``plastic_moment_n`` [N·mm/mm = N] and each parameter, the free
    parameters, those held at a bound). Both are ``None`` unless ``converged``.
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

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


# -- the loop ----------------------------------------------------------------------------------
class _Runs:
    """Full-solver runs through the result cache; counts what this calibration used."""

    def __init__(self, problem: CalibrationProblem, cache_dir: Path, *, jobs: int) -> None:
        self.problem = problem
        self.cache = ResultCache(cache_dir)
        self.jobs = jobs
        self.used: set[str] = set()
        self.X: list[np.ndarray] = []
        self.groups: list[int] = []
        self.curves: list[np.ndarray] = []
        self.failures: list[str] = []
        self._seen: set[tuple[str, int]] = set()

    def _items(
        self, thetas: np.ndarray, groups: Sequence[int]
    ) -> list[tuple[np.ndarray, int, dict[str, Any]]]:
        names = self.problem.space.names
        return [
            (theta, g, self.problem.inputs(dict(zip(names, theta, strict=True)), g))
            for theta, g in zip(thetas, groups, strict=True)
        ]

    def keys(self, thetas: np.ndarray, groups: Sequence[int]) -> list[str]:
        """The result-cache keys of these runs."""
        return [input_hash(inputs) for _, _, inputs in self._items(thetas, groups)]

    def cost(self, thetas: np.ndarray, groups: Sequence[int]) -> int:
        """Solver runs that :meth:`run` would add to :attr:`calls`."""
        return len(set(self.keys(thetas, groups)) - self.used)

    def run(self, thetas: np.ndarray, groups: Sequence[int]) -> list[dict[str, Any] | None]:
        """Solve each (theta, group); the curves (on whole degrees) or None if failed."""
        items = self._items(thetas, groups)
        keys = [input_hash(inputs) for _, _, inputs in items]
        results: dict[int, dict[str, Any]] = {}
        todo = []
        for i, key in enumerate(keys):
            hit = self.cache.get(key)
            if hit is None:
                todo.append(i)
            else:
                results[i] = hit
        from ..solvers._batch import _run as run_pool

        for i, result in run_pool(todo, [it[2] for it in items], solve_inputs, self.jobs):
            self.cache.put(keys[i], items[i][2], result)
            results[i] = result
        out: list[dict[str, Any] | None] = []
        for i, (theta, g, _) in enumerate(items):
            self.used.add(keys[i])
            result = results[i]
            if result["status"] != "ok":
                self.failures.append(result["reason"])
                out.append(None)
                continue
            curve = np.interp(self.problem.angle_deg, result["angle_deg"], result["force_n"])
            if (keys[i], g) not in self._seen:
                self._seen.add((keys[i], g))
                self.X.append(np.asarray(theta, float))
                self.groups.append(g)
                self.curves.append(curve)
            out.append({"curve": curve, "key": keys[i]})
        return out

    @property
    def calls(self) -> int:
        return len(self.used)


def _load(
    study: str | Path | StudySpec,
    effects: Sequence[str] | None,
    plugins: Sequence[str],
) -> tuple[StudySpec, MeasurementSet, tuple[str, ...], float]:
    for module in plugins:
        load_plugin(module)
    spec = study if isinstance(study, StudySpec) else load_study(study)
    if spec.measurements_file is None:
        raise InputDataError(
            f"study {spec.name!r} has no [measurements] file; add one to calibrate against curves"
        )
    data = load_measurements(spec.measurements_file)
    chosen = tuple(spec.effects) if effects is None else tuple(effects)
    for name in chosen:
        get_effect(name)  # unknown names fail here, before anything is written
    noise = spec.noise_n if spec.noise_n is not None else data.noise_n
    if noise is None:
        raise InputDataError(
            f"{spec.measurements_file}: no replicate tests to estimate the noise; "
            "add [measurements] noise_n (N) to the study"
        )
    return spec, data, chosen, float(noise)


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
        Budget of full-solver runs (default: ``[budget] calibration_solver_calls``).
    jobs : int
        Worker processes for the runs of one verification.
    tests : sequence, optional
        Calibrate on these tests only (used by the diagnosis).
    record : bool
        Keep the verifications as trials of ``<name>/calibrate/<model>``.

    Returns
    -------
    CalibrationResult
    """
    spec, data, chosen, noise = _load(study, effects, plugins)
    problem = CalibrationProblem(spec, data, chosen, tests=tests)
    budget = max_solver_calls or spec.budget.calibration_solver_calls
    url = storage or spec.default_storage()
    name = calibration_study_name(spec, chosen)
    runs = _Runs(problem, spec.directory / ".solver-cache", jobs=jobs)
    loop = _Loop(
        problem,
        runs,
        budget=budget,
        seed=spec.seed,
        progress=progress,
        label=name,
        noise=noise,
        dof_noise=noise_dof(spec.noise_n is not None, data.noise_dof),
    )
    loop.run(spec.budget.surrogate_trials)
    fit, best = loop.best_fit(), loop.best()
    if best is None:
        reason = runs.failures[0] if runs.failures else "no verification fitted in the budget"
        raise InputDataError(
            f"calibration of {name} found no parameter point the solver could run at every "
            f"test ({reason}); check the parameter ranges"
        )
    # converged: the best verified point is a local optimum the first-order test passed
    converged = fit is not None and fit.converged and fit.rmse <= best["rmse"]
    theta = best["theta"]
    misfit, p_value, determination = None, None, None
    if fit is not None and converged:
        p_value = loop.p_value(fit)
        misfit = "within the noise" if p_value >= SIGNIFICANCE else "systematic"
        determination = _determination(problem, fit).to_json()
    status = "converged" if converged else "budget_exhausted"
    result = CalibrationResult(
        params=dict(zip(problem.space.names, map(float, theta), strict=True)),
        rmse_n=float(best["rmse"]),
        noise_n=noise,
        solver_calls=runs.calls,
        effects=list(chosen),
        rmse_per_test_n=best["per_test"],
        status=status,
        predicted_gain=fit.predicted_gain if converged else None,
        misfit=misfit,
        misfit_p_value=p_value,
        determination=determination,
        iterations=loop.iterations,
        study=name,
        storage=url,
        message="",
    )
    result = replace(result, message=_message(problem, result, fit))
    if record:
        _record(url, name, problem, loop.verified, result, data_hash(spec))
    return result


def coat_section(params: Mapping[str, float], thickness_mm: float) -> tuple[float, float]:
    """Bending stiffness D [N·mm] and plastic moment Mp [N] per unit width of a coating
    given in the paper's units (``ecoat_gpa``, ``scoat_gpa``, ``tcoat_mm``)."""
    tcoat = params["tcoat_mm"]
    return (
        bending_stiffness(gpa_to_mpa(params["ecoat_gpa"]), tcoat, thickness_mm),
        plastic_moment(gpa_to_mpa(params["scoat_gpa"]), tcoat, thickness_mm),
    )


def _determination(problem: CalibrationProblem, fit: LocalFit) -> Any:
    """What the curves determine at a converged local fit (bending stiffness, plastic
    moment per unit width, every parameter)."""
    space, thickness = problem.space, problem.spec.rig.thickness_mm

    def stiffness(p: Mapping[str, float]) -> float:
        return coat_section(p, thickness)[0]

    def moment(p: Mapping[str, float]) -> float:
        return coat_section(p, thickness)[1]

    return determine(
        space.names,
        np.array([p.low for p in space]),
        np.array([p.high for p in space]),
        np.array([p.log for p in space]),
        fit.theta,
        fit.jacobian,
        fit.residual,
        fit.at_bound,
        combinations={
            "bending_stiffness_nmm": ("D ∝ Ecoat·Tcoat", stiffness),
            "plastic_moment_n": ("Mp ∝ Scoat·Tcoat", moment),
        },
    )


def _message(problem: CalibrationProblem, result: CalibrationResult, fit: LocalFit | None) -> str:
    rmse, noise = result.rmse_n, result.noise_n
    text = (
        f"{model_label(result.effects)}: RMSE {rmse:.4g} N over {problem.n_points} points of "
        f"{len(problem.test_ids)} tests, noise {noise:.4g} N ({rmse / noise:.2f}× noise), "
        f"{result.solver_calls} solver calls, {result.status}"
    )
    if result.status != "converged":
        reported = np.array(list(result.params.values()))
        reported_is_fit = fit is not None and np.array_equal(fit.theta, reported)
        why = fit.message if reported_is_fit else "no local fit ended at the best verified point"
        return f"{text} ({why}; best verified point so far — raise --budget)"
    assert result.determination is not None
    return (
        f"{text} ({fit.message if fit else ''}); {result.misfit} (F-test p = "
        f"{result.misfit_p_value:.2g}); {result.determination['statement']}"
    )


def data_hash(spec: StudySpec) -> str:
    """SHA-256 of the measurement file's bytes (which data a calibration saw)."""
    assert spec.measurements_file is not None
    return hashlib.sha256(Path(spec.measurements_file).read_bytes()).hexdigest()


class _Loop:
    """The global phase on the surrogate, then the local phase with the full solver.

    1. *Global*: an initial design, then search on the surrogate and verify, until
       the surrogate sees nothing better than the best verified point (or
       ``STALE_LIMIT`` verifications bring no improvement). It finds the basin; it
       proves nothing.
    2. *Local*: :func:`~surrogate.calibration._local.local_fit` from the best verified point,
       until the first-order test holds at a verified point.
    3. *Other basins*: the surrogate, refitted on every run so far, is searched
       again; where it predicts a fit better than the best local optimum (however
       near: a second optimum can lie within 5 % of a range behind a barrier), the
       point is verified and, if it is better, fitted locally too (at most
       ``BASIN_CHECKS`` local fits).
    """

    def __init__(
        self,
        problem: CalibrationProblem,
        runs: _Runs,
        *,
        budget: int,
        seed: int,
        progress: bool,
        label: str,
        noise: float,
        dof_noise: float,
    ) -> None:
        self.problem, self.runs, self.budget = problem, runs, budget
        self.seed, self.progress, self.label = seed, progress, label
        self.noise, self.dof_noise = noise, dof_noise
        self.verified: list[dict[str, Any]] = []
        self.fits: list[LocalFit] = []
        self.iterations = 0

    def _say(self, text: str) -> None:
        if self.progress:
            print(f"[{self.label}] {text}", file=sys.stderr, flush=True)

    def best(self) -> dict[str, Any] | None:
        return min(self.verified, key=lambda v: v["rmse"]) if self.verified else None

    def best_fit(self) -> LocalFit | None:
        return min(self.fits, key=lambda f: f.rmse) if self.fits else None

    def run(self, surrogate_trials: int) -> None:
        model = CurveSurrogate(self.problem, seed=self.seed)
        self._global(model, surrogate_trials)
        start = self.best()
        residuals = ResidualModel(self.problem, self.runs, budget=self.budget)
        for check in range(BASIN_CHECKS):
            if start is None:
                break
            self._local(residuals, start)
            # a better point found on the last pass would be left unfitted: none is sought
            start = self._other_basin(model, surrogate_trials) if check + 1 < BASIN_CHECKS else None
        G = len(self.problem.groups)
        for theta in self._valley_starts():
            if self.runs.calls + G > self.budget:
                break
            record = self._verify(theta, None)
            if record is not None:
                self._local(residuals, record)

    def p_value(self, fit: LocalFit) -> float:
        """F-test of the fit's misfit against the noise (small: systematic)."""
        rss = float(fit.residual @ fit.residual)
        dof = self.problem.n_points - len(fit.theta)
        return misfit_p_value(rss, dof, self.noise, self.dof_noise)

    def _valley_starts(self) -> list[np.ndarray]:
        """Both ends of the least determined direction, when the misfit is near the noise
        but not quite within it.

        Curves leave a valley of equally good coatings (D and Mp fixed, Tcoat
        free); a fit can stop along it short of a better point (seen before the
        local phase moved in (log D, log Mp, Tcoat): a thick stiff coat at 1.14× the
        truth's RMSE, Tcoat 0.0999 mm against 0.09 mm). A safeguard: a misfit with
        weak evidence against the noise (F-test p < ``VALLEY_P``) and within
        ``VALLEY_RMSE`` × noise is where such a point would show; a larger misfit is
        the model's, not the start's.
        """
        fit = self.best_fit()
        G = len(self.problem.groups)
        if fit is None or not fit.converged or self.runs.calls + 2 * G > self.budget:
            return []
        p_value = self.p_value(fit)
        if p_value >= VALLEY_P or fit.rmse > VALLEY_RMSE * self.noise:
            return []
        direction = _determination(self.problem, fit).directions[-1]["weights"]  # in z
        move = np.array([direction.get(p.name, 0.0) / p.span for p in self.problem.space])
        move *= VALLEY_STEP / np.max(np.abs(move))
        starts = [np.clip(fit.unit + sign * move, 0.0, 1.0) for sign in (1.0, -1.0)]
        starts = [u for u in starts if np.max(np.abs(u - fit.unit)) > FIRST_ORDER_BOX]
        self._say(
            f"misfit near the noise but not within it (p = {p_value:.2g}): trying "
            f"{len(starts)} start(s) along the least determined direction"
        )
        return [self.problem.space.from_unit(u[None, :])[0] for u in starts]

    def _global(self, model: CurveSurrogate, surrogate_trials: int) -> None:
        problem = self.problem
        d, G = len(problem.space), len(problem.groups)
        n0 = max(2 * d + 2, 2 * G)
        unit = qmc.LatinHypercube(d=d, seed=self.seed).random(n0)
        thetas = problem.space.from_unit(unit)
        self.runs.run(thetas, [i % G for i in range(n0)])
        self._say(f"initial design: {self.runs.calls} solver runs ({G} condition groups)")
        # the local phase needs what is left: the global phase takes at most half the budget
        stale, budget = 0, max(self.budget // 2, self.runs.calls + G)
        while self.runs.calls + G <= budget and len(self.runs.X) >= 3:
            self.iterations += 1
            self._fit(model)
            candidate, predicted = self._search(model, surrogate_trials)
            previous = self.best()
            if previous is not None and predicted >= (1.0 - SETTLED) * previous["rmse"]:
                self._say(
                    f"global phase done: the surrogate's best RMSE {predicted:.4g} N does not "
                    f"beat the best verified {previous['rmse']:.4g} N"
                )
                return
            verified = self._verify(candidate, predicted)
            if verified is None:
                stale += 1
            else:
                improved = previous is None or verified["rmse"] < previous["rmse"] * (1 - SETTLED)
                stale = 0 if improved else stale + 1
                self._say(
                    f"verified: RMSE {verified['rmse']:.4g} N (predicted {predicted:.4g}), "
                    f"best {self.best()['rmse']:.4g} N, {self.runs.calls} solver calls"
                )
            if stale >= STALE_LIMIT:
                self._say(f"global phase done: {STALE_LIMIT} verifications without improvement")
                return

    def _fit(self, model: CurveSurrogate) -> None:
        runs = self.runs
        model.fit(np.array(runs.X), np.array(runs.groups), np.array(runs.curves))

    def _local(self, residuals: ResidualModel, start: dict[str, Any]) -> None:
        self._say(f"local phase from the verified point at RMSE {start['rmse']:.4g} N")
        try:
            fit = local_fit(residuals, start["theta"])
        except (SolverFailed, BudgetSpent) as failed:
            self._say(f"local phase not started: {failed}")
            return
        self.fits.append(fit)
        self.verified.append(
            {
                "theta": fit.theta,
                "rmse": fit.rmse,
                "per_test": self.problem.rmse_per_test(fit.curves),
                "predicted": None,
                "keys": residuals.keys(fit.theta),
                "curves": fit.curves,
                "calls": self.runs.calls,
                "phase": "local",
            }
        )
        self._say(
            f"local phase: RMSE {fit.rmse:.4g} N, {self.runs.calls} solver calls; {fit.message}"
        )

    def _other_basin(self, model: CurveSurrogate, surrogate_trials: int) -> dict[str, Any] | None:
        """A verified start in another basin the surrogate shows, or None."""
        best = self.best_fit()
        G = len(self.problem.groups)
        if best is None or not best.converged or self.runs.calls + G > self.budget:
            return None
        self.iterations += 1
        self._fit(model)
        candidate, predicted = self._search(model, surrogate_trials)
        if predicted >= (1.0 - SETTLED) * best.rmse:
            self._say(
                f"no other basin: the surrogate's best ({predicted:.4g} N) is no better "
                f"than the local optimum's {best.rmse:.4g} N"
            )
            return None
        verified = self._verify(candidate, predicted)
        if verified is None or verified["rmse"] >= best.rmse:
            self._say("another basin the surrogate showed is not better when verified")
            return None
        self._say(f"another basin: verified RMSE {verified['rmse']:.4g} N; fitting it locally")
        return verified

    def _verify(self, theta: np.ndarray, predicted: float | None) -> dict[str, Any] | None:
        G = len(self.problem.groups)
        out = self.runs.run(np.repeat(theta[None, :], G, axis=0), list(range(G)))
        if any(o is None for o in out):
            return None
        curves = np.array([o["curve"] for o in out])  # type: ignore[index]
        record = {
            "theta": theta,
            "rmse": self.problem.rmse(curves),
            "per_test": self.problem.rmse_per_test(curves),
            "predicted": predicted,
            "keys": [o["key"] for o in out],  # type: ignore[index]
            "curves": curves,
            "calls": self.runs.calls,
            "phase": "global",
        }
        self.verified.append(record)
        return record

    def _search(self, model: CurveSurrogate, n_trials: int) -> tuple[np.ndarray, float]:
        """TPE on the surrogate's RMSE, then L-BFGS-B from the best starts.

        Returns the candidate and its predicted RMSE.
        """
        problem, space = self.problem, self.problem.space

        def objective(unit: np.ndarray) -> np.ndarray:
            X = space.from_unit(np.clip(np.atleast_2d(unit), 0.0, 1.0))
            return problem.batch_rmse(model.predict(X))

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        sampler = optuna.samplers.TPESampler(
            seed=self.seed * 1000 + self.iterations, multivariate=True, n_startup_trials=40
        )
        search = optuna.create_study(direction="minimize", sampler=sampler)
        distributions = {
            p.name: optuna.distributions.FloatDistribution(p.low, p.high, log=p.log) for p in space
        }
        best = self.best()
        if best is not None:
            search.enqueue_trial(dict(zip(space.names, map(float, best["theta"]), strict=True)))
        done = 0
        while done < n_trials:
            trials = [search.ask(distributions) for _ in range(_SEARCH_BATCH)]
            X = np.array([[t.params[n] for n in space.names] for t in trials])
            values = objective(space.to_unit(X))
            for trial, value in zip(trials, values, strict=True):
                search.tell(trial, float(value))
            done += len(trials)
        starts = [space.to_unit(np.array([[search.best_params[n] for n in space.names]]))[0]]
        if best is not None:
            starts.append(space.to_unit(best["theta"][None, :])[0])
        result_x, result_f = starts[0], np.inf
        for start in starts:
            found = minimize(
                lambda u: float(objective(u)[0]),
                start,
                method="L-BFGS-B",
                bounds=[(0.0, 1.0)] * len(space),
                options={"maxiter": 200},
            )
            if found.fun < result_f:
                result_x, result_f = found.x, float(found.fun)
        theta = space.from_unit(np.clip(result_x, 0.0, 1.0)[None, :])[0]
        # exp∘log may round a bound past itself; the verification stays inside
        return space.clip(theta), result_f


def _record(
    url: str,
    name: str,
    problem: CalibrationProblem,
    verified: list[dict[str, Any]],
    result: CalibrationResult,
    data_sha: str,
) -> None:
    """Verifications as trials of the study ``name``; the result as a study attribute."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name=name, storage=url, load_if_exists=True)
    known = {
        t.user_attrs.get("verification_key")
        for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    }
    distributions = {
        p.name: optuna.distributions.FloatDistribution(p.low, p.high, log=p.log)
        for p in problem.space
    }
    for item in verified:
        key = hashlib.sha256("".join(item["keys"]).encode()).hexdigest()
        if key in known:
            continue
        space = problem.space
        inside = space.clip(item["theta"])
        params = dict(zip(problem.space.names, map(float, inside), strict=True))
        known.add(key)
        trial = optuna.trial.create_trial(
            params=params,
            distributions=distributions,
            value=item["rmse"],
            user_attrs={
                "verification_key": key,
                "phase": item["phase"],
                "predicted_rmse_n": item["predicted"],
                "rmse_per_test_n": item["per_test"],
                "solver_calls": item["calls"],
                "effects": list(problem.effects),
                "data_sha256": data_sha,
            },
        )
        study.add_trial(trial)
    study.set_user_attr("result", json.loads(json.dumps(result.to_json())))
    study.set_user_attr("data_sha256", data_sha)
    _note(study, calibration_note(result.to_json()))


def calibration_note(result: Mapping[str, Any]) -> list[str]:
    """The calibration's status and what the curves determine, as Markdown lines
    (the dashboard note of the calibration study; compare and diagnose repeat it)."""
    lines = [f"## Calibration: {result['status']}", "", result["message"]]
    determination = result.get("determination")
    if determination:
        lines += ["", "| quantity | value | 95 % interval |", "|---|---|---|"]
        for key, c in determination["combinations"].items():
            span = "not determined" if c["low"] is None else f"{c['low']:.4g} – {c['high']:.4g}"
            lines.append(f"| {key} | {c['value']:.4g} | {span} |")
        for name, value in result["params"].items():
            interval = determination["intervals"].get(name)
            span = (
                "held at a bound" if interval is None else f"{interval[0]:.4g} – {interval[1]:.4g}"
            )
            free = " (free within its range)" if name in determination["free"] else ""
            lines.append(f"| {name} | {value:.4g} | {span}{free} |")
    return lines


def _note(study: optuna.Study, lines: list[str]) -> None:
    """Markdown note of the study in optuna-dashboard (skipped without it)."""
    try:
        from optuna_dashboard import save_note
    except ImportError:
        return
    save_note(study, "\n".join(lines))
