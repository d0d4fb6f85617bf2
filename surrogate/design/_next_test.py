"""``next-test``: which test, inside the lab's ``[design]``, settles what the data leave open.

After a calibration (and, where there is one, a diagnosis) of the study's model:

1. **Precision.** Each walked profile side of the calibration's intervals ended at a
   re-fit — an alternative fit the measured curves hardly tell from the optimum (at the
   threshold, or at the range's end of an open side); a projected side of Ecoat or Scoat
   has Tcoat's re-fit where it is open because Tcoat's side is, else none. Each candidate test
   (:func:`~._candidates.candidate_tests`) is run at the optimum and at every
   alternative; what its replicates would add between them (:mod:`._information`)
   moves each side in: the predicted interval of every quantity, in its own units.
   The goal (``--goal``, else the least determined quantity some candidate settles)
   ranks the candidates.
2. **Discrimination.** The diagnosis's leader and those tied with it (else its
   runner-up), each at its own calibrated point: the candidates where their curves
   differ by two noise levels, or — where none does — that no test inside
   ``[design]`` tells them apart.
3. **Testability.** An effect whose condition never varies in the measurements cannot
   be tested by them at all: it is listed with the test that would make it testable.

Runs are the built-in solver's (with an external full solver: its prior, the built-in
model, uncorrected — the correction is not kept in the storage; the message says so).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna

from .._errors import InputDataError
from .._io import check_output_folder
from .._log import show_progress
from .._pool import one_blas_thread_within
from ..calibration._calibrate import calibration_note, data_hash
from ..calibration._compare import latest_calibration
from ..calibration._loop import profiled_quantities
from ..calibration._problem import CalibrationProblem, calibration_study_name, load_calibration
from ..calibration._profile import end_value
from ..effects import available_effects, get_effect
from ..solvers._batch import solved, solver_inputs
from ..solvers._cache import ResultCache, input_hash
from ..solvers._fidelity import LOW_FIDELITY
from ..storage._optuna import quiet_optuna
from ..storage._storage import check_storage_url, open_storage, refuse_in_memory
from ..study._conditions import RIG_CONDITIONS, rig_for
from ..study._design import conditions_text
from ._candidates import as_json, candidate_tests
from ._information import moved_side, refit_chi2, separated

__all__ = ["NextTestResult", "next_test"]

SETTLES = 0.9  # a candidate settles a quantity where it cuts its interval's width by 10 %
# what a test that does not record a condition was run at (the rig's and the effects' own)
SEEN_SHARE = 1e-3  # a test that narrows a quantity by less than this share there sees nothing
PRIOR_UNIT = 0.5  # a Gaussian prior of this share of each range keeps unseen ones finite
# why no candidate is predicted to close an open side (``NextTestResult.left_open``)
LEFT_OPEN = {
    "near_fit": "a candidate inside [design] sees it near today's fit but not where the profile "
    "ended the side, so it closes the side only if the coat lies where it still sees it",
    "insensitive": "no candidate inside [design] is sensitive to it near today's fit or where "
    "the profile ended the side (a linear judgement: where the coat lies elsewhere, one may "
    "still close it)",
    "absorbed": "the other parameters re-fit to each candidate sensitive to it where the "
    "profile ended the side",
    "range_end": "a candidate moves the side's end in, not off the range's end",
    "no re-fit": "the profile left no re-fit at the side's end to weigh the candidates against",
}
UNRECORDED: dict[str, Any] = {"direction": "warp", "tension_n": 0.0, "rate_deg_s": 90.0}

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class NextTestResult:
    """Keys of ``surrogate next-test --json``.

    ``recommended``: the best ``count`` candidate tests for ``goal``, best first — each
    its ``conditions``, ``replicates``, ``goal``, ``predicted`` (every quantity's
    interval after the test, centred on today's fit: ``{value, low, high, kind}``,
    ``low``/``high`` None on an open side, ``width_now``/``width_after`` in its declared
    scale and ``precision``, the width in words — the test decides where the interval
    will lie), ``settles`` (the quantities it narrows by ≥ 10 %) and ``separates``
    (pairs of effects whose fits its curves tell apart). ``reference``:
    the same for the replicates of the reference test (the measurements' first), the
    baseline. ``untestable``: effects whose condition never varies in the data, each
    ``{effect, reason, test}``; ``inseparable``: pairs no candidate tells apart, each
    ``{effects, largest_difference_n, at, reason}``; ``left_open``: the quantities with a
    side the data leave open that no candidate is predicted to close, each ``{quantity,
    kind, now, sides, ends, reasons, near_fit}`` (``now`` today's interval in words,
    ``sides`` those sides, ``ends`` the quantity at each one's re-fit, ``reasons`` each
    side's key of :data:`LEFT_OPEN`, ``near_fit`` the candidate that settles it near
    today's fit, where that is a side's reason). ``candidates`` counts the tests
    ranked, ``solver_calls`` the built-in runs it took; ``figure`` the PNG of the
    recommended test's curves; ``notes`` what the ranking ran on.
    """

    study: str
    goal: str | None
    recommended: list[dict[str, Any]]
    reference: dict[str, Any] | None
    untestable: list[dict[str, Any]]
    inseparable: list[dict[str, Any]]
    candidates: int
    solver_calls: int
    figure: str | None
    message: str
    notes: list[str] = field(default_factory=list)
    left_open: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@one_blas_thread_within
def next_test(
    study: Any,
    *,
    goal: str | None = None,
    count: int = 3,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
    storage: str | None = None,
    output_dir: str | Path | None = None,
    plots: bool = True,
    progress: bool = True,
    jobs: int = 1,
) -> NextTestResult:
    """Rank the tests inside ``[design]`` by what they would settle.

    Parameters
    ----------
    study : path or StudySpec
        A study with ``[measurements]`` and ``[design]``, calibrated.
    goal : str, optional
        The quantity to settle (``plastic_moment_n``, ``tcoat_mm``, an effect's
        ``effect.param``, …); default: the least determined one a candidate settles.
    count : int
        Recommended tests to list (≥ 1).
    effects : sequence of str, optional
        The model's effects (default: the study's ``[model] effects``).
    output_dir : path, optional
        Folder of the figure (default: the study's).
    """
    if not isinstance(count, int) or count < 1:
        raise InputDataError(f"--count must be a whole number ≥ 1, got {count!r}")
    if plots and output_dir is not None:
        check_output_folder(output_dir)
    if progress:
        show_progress()
    spec, data, chosen, noise = load_calibration(study, effects, plugins)
    if spec.design.empty:
        raise InputDataError(
            f"study {spec.name!r} has no [design] section; add what your lab can vary for "
            "the next test, e.g. [design] bending_length_mm = { low = 5.0, high = 17.5 }"
        )
    url = storage or spec.default_storage()
    check_storage_url(url)
    refuse_in_memory(url, "`next-test` (it reads the calibration)")
    name = calibration_study_name(spec, chosen)
    stored = latest_calibration(url, name)
    _check_calibration(stored, name)
    assert stored is not None
    problem = CalibrationProblem(spec, data, chosen)
    planner = _Planner(problem, stored, noise, jobs)
    if goal is not None and goal not in planner.quantities:
        raise InputDataError(
            f"--goal {goal!r} is not a quantity of this calibration; use one of "
            f"{', '.join(planner.quantities)}"
        )
    result = planner.rank(goal, count, _diagnosis(url, name), output_dir if plots else False)
    _record(url, name, result, stored, data_hash(spec))
    if progress:
        _LOG.info("[%s] %s", name, result.message)
    return result


def _check_calibration(stored: Mapping[str, Any] | None, name: str) -> None:
    if stored is None:
        raise InputDataError(
            f"no calibration of model {name!r} yet; run `surrogate calibrate` first"
        )
    if stored.get("status") != "converged" or not stored.get("determination"):
        raise InputDataError(
            f"the last calibration of {name!r} is {stored.get('status')}, not at a verified "
            "local optimum: what the data leave open is stated only there; calibrate again "
            "(a larger --budget) first"
        )
    if "points" not in next(iter(stored["determination"]["combinations"].values()), {}):
        raise InputDataError(
            f"the last calibration of {name!r} has no profile intervals (an older record or "
            "one whose profiles did not run); calibrate again first"
        )


def _check_rig(design: Any, reference: Mapping[str, Any], rig: Any, where: Any) -> None:
    """Every end of a ``[design]`` range of a rig condition is a test the rig can run (a
    bending length the strip's free length holds on the probe up to 90°): else one line
    naming the end and the fix, before any run."""
    for span in design.ranges:
        if span.name not in RIG_CONDITIONS:
            continue
        for end, value in (("low", span.low), ("high", span.high)):
            try:
                rig_for(rig, {**reference, span.name: value})
            except InputDataError as error:
                raise InputDataError(
                    f"{where}: design.{span.name} {end} = {value:g} is a test the rig cannot "
                    f"run ({error}); or narrow design.{span.name}"
                ) from None


class _Planner:
    """The candidates' runs and predictions for one calibrated model."""

    def __init__(
        self, problem: CalibrationProblem, stored: Mapping[str, Any], noise: float, jobs: int
    ) -> None:
        self.problem, self.stored, self.noise, self.jobs = problem, stored, noise, jobs
        spec = problem.spec
        self.design = spec.design
        self.cache = ResultCache(spec.directory / ".solver-cache")
        self.used: set[str] = set()
        determination = stored["determination"]
        self.entries = {**determination["combinations"], **determination["intervals"]}
        self.quantities = {
            q.name: q for q in profiled_quantities(problem) if q.name in self.entries
        }
        dof = determination["dof"]
        from scipy import stats

        t = float(stats.t.ppf(0.975, max(dof, 1)))
        # the threshold in units of σ²: t² · s²/σ² (3.84 where the misfit is the noise)
        self.threshold = t * t * (determination["sigma_n"] / noise) ** 2
        self.reference = problem.data.conditions_of(problem.test_ids[0])
        _check_rig(self.design, self.reference, spec.rig, spec.path)

    # -- runs ----------------------------------------------------------------------------------
    def curves(
        self,
        fits: Sequence[tuple[Sequence[str], Mapping[str, float]]],
        tests: Sequence[Mapping[str, Any]],
    ) -> np.ndarray:
        """Curves (F, T, A) [N] of each fit (its effects and parameters) at each test's
        conditions, on the rig's whole degrees (NaN where the solver failed)."""
        items = []
        for effects, params in fits:
            coating = {k: float(v) for k, v in params.items() if "." not in k}
            by_effect: dict[str, dict[str, float]] = {name: {} for name in effects}
            for key, value in params.items():
                if "." in key:
                    effect, param = key.split(".", 1)
                    by_effect.setdefault(effect, {})[param] = float(value)
            for test in tests:
                items.append(
                    solver_inputs(
                        coating,
                        self.problem.spec.rig,
                        solver=LOW_FIDELITY,
                        effects=by_effect or None,
                        conditions=dict(test),
                    )
                )
        keys = [input_hash(inputs) for inputs in items]
        results, todo = self.cache.hits(keys)
        for j, result in solved([items[i] for i in todo], self.jobs):
            self.cache.put(keys[todo[j]], items[todo[j]], result)
            results[todo[j]] = result
        self.used.update(keys)
        angle = self.problem.angle_deg
        out = np.full((len(fits) * len(tests), angle.size), np.nan)
        for i, result in results.items():
            if result["status"] == "ok":
                out[i] = np.interp(angle, result["angle_deg"], result["force_n"])
        return out.reshape(len(fits), len(tests), angle.size)

    # -- the ranking ---------------------------------------------------------------------------
    def rank(
        self,
        goal: str | None,
        count: int,
        diagnosis: Mapping[str, Any] | None,
        output_dir: str | Path | bool | None,
    ) -> NextTestResult:
        tests = candidate_tests(self.design, self.reference, seed=self.problem.spec.seed)
        tests.append(dict(self.reference))  # the baseline: the reference test again
        chosen = tuple(self.problem.effects)
        alternatives = self._alternatives()
        fits = [(chosen, self.stored["params"])] + [(chosen, alt["params"]) for alt in alternatives]
        curves = self.curves(fits, tests)
        r = self.design.replicates
        shrink = self._shrink(self._linearised([self.stored["params"]], tests)[0], r)
        refit, far = self._at_open_sides(alternatives, tests, curves[0], r)
        predicted = [
            self._predicted(curves[:, k], alternatives, shrink[k], far[:, k], refit[:, k])
            for k in range(len(tests))
        ]
        pairs, pair_curves = self._pairs(diagnosis, tests)
        goal = goal or self._default_goal(predicted[:-1])
        order = sorted(
            range(len(tests) - 1),
            key=lambda k: (
                predicted[k][goal]["width_after"] if goal else 0.0,
                sum(p["width_after"] / max(p["width_now"], 1e-300) for p in predicted[k].values()),
            ),
        )
        entry = lambda k: self._entry(tests[k], predicted[k], goal, pairs, pair_curves, k)  # noqa: E731
        recommended = [entry(k) for k in order[:count]] if goal or pairs else []
        reference = entry(len(tests) - 1)
        inseparable = self._inseparable(pairs, pair_curves, tests)
        untestable = self._untestable()
        left_open = self._left_open(predicted, alternatives, refit, far, shrink, tests)
        figure = (
            None
            if output_dir is False or not recommended
            else self._figure(tests[order[0]], curves[:, order[0]], alternatives, goal, output_dir)
        )
        message = self._message(goal, recommended, reference, untestable, inseparable, left_open)
        return NextTestResult(
            study=calibration_study_name(self.problem.spec, chosen),
            goal=goal,
            recommended=recommended,
            reference=reference,
            untestable=untestable,
            inseparable=inseparable,
            candidates=len(tests) - 1,
            solver_calls=len(self.used),
            figure=figure,
            message=message,
            left_open=left_open,
            notes=[
                "ranked on the built-in model"
                + (
                    f" (the study's solver is {self.problem.spec.solver}: its correction "
                    "is not kept in the storage, so the built-in model is uncorrected)"
                    if self.problem.spec.solver != LOW_FIDELITY
                    else ""
                )
            ],
        )

    def _alternatives(self) -> list[dict[str, Any]]:
        """Every profile side's re-fit: ``{quantity, side, params, ratio}``."""
        found = []
        for name in self.quantities:
            for side, point in (self.entries[name].get("points") or {}).items():
                if point is not None:
                    found.append({"quantity": name, "side": side, **point})
        return found

    # -- the information a test adds --------------------------------------------------------
    def _linearised(
        self, points: Sequence[Mapping[str, float]], tests: list[dict[str, Any]]
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]]:
        """At each of ``points`` (parameters), in the fit coordinates ``x`` where the valley
        of equally good coats is straight (differences taken in the declared unit
        coordinates straddle it, and made a free Ecoat look settled to ±0.05 %): ``(x,
        J, F, S, g)`` — the measured curves' Jacobian ``J`` (n, p) (the residual model's on
        the built-in solver, as every run here: its runs mostly the calibration's, in the
        result cache), the tests' curves ``F`` (T, A), their sensitivities ``S`` (T, A, p)
        and every quantity's ``g = ∂q/∂x`` — the same differences as ``J``'s
        (:meth:`ResidualModel.shifted`: inwards at a bound and where Ecoat or Scoat is held
        at theirs). ``g`` by central differences instead (``quantity_gradient``) had half
        the slope where one side is held and a column where ``J`` had none, and a 5 mm
        test was predicted to pin D to ±0.0002 % where it gave ±0.03 % (benchmarks/
        next_test.py, 0.7/0.3/0.015: realised over predicted 145)."""
        from ..calibration._fidelity import CorrectedRuns
        from ..calibration._local import ResidualModel
        from ..calibration._loop import SolverRuns

        space, chosen = self.problem.space, tuple(self.problem.effects)
        cache = self.problem.spec.directory / ".solver-cache"
        runs = (
            SolverRuns(self.problem, cache, jobs=self.jobs)
            if self.problem.spec.solver == LOW_FIDELITY
            else CorrectedRuns(self.problem, cache, jobs=self.jobs, correction=None)
        )
        model = ResidualModel(self.problem, runs)
        at, fits = [], []
        for params in points:
            x = model.pin(np.array([params[n] for n in space.names]))
            shifted = [model.shifted(x, j) for j in range(x.size)]
            at.append((x, shifted, model.jacobian(x)))
            fits.append((chosen, dict(params)))
            fits += [
                (chosen, dict(zip(space.names, map(float, model.point(z)), strict=True)))
                for z, _ in shifted
            ]
        self.used.update(runs.used)
        p = len(space.names)
        curves = self.curves(fits, tests).reshape(len(points), p + 1, len(tests), -1)
        out = []
        for (x, shifted, data), c in zip(at, curves, strict=True):
            steps = np.array([step for _, step in shifted])
            sensitivity = np.nan_to_num((c[1:] - c[0]) / steps[:, None, None]).transpose(1, 2, 0)
            ends, start = [model.point(z) for z, _ in shifted], model.point(x)
            gradients = {
                n: np.array([q.scaled(e) - q.scaled(start) for e in ends]) / steps
                for n, q in self.quantities.items()
            }
            out.append((x, data, c[0], sensitivity, gradients))
        return out

    def _information(
        self, data: np.ndarray, sensitivity: np.ndarray | None, replicates: int
    ) -> np.ndarray:
        """The Fisher information in ``x`` of the measured curves (and of a test's
        replicates), a Gaussian prior of ``PRIOR_UNIT`` of each coordinate keeping what no
        curve sees finite."""
        s2 = self.stored["determination"]["sigma_n"] ** 2
        information = data.T @ data / s2 + np.eye(data.shape[1]) / PRIOR_UNIT**2
        if sensitivity is not None:
            information = information + replicates * sensitivity.T @ sensitivity / s2
        return information

    def _half(self, information: np.ndarray, gradient: np.ndarray) -> float:
        """The linear 95 % half-width, in its declared scale, of a quantity of gradient
        ``gradient``."""
        s2 = self.stored["determination"]["sigma_n"] ** 2
        t = math.sqrt(self.threshold * self.noise**2 / s2)
        return t * math.sqrt(max(float(gradient @ np.linalg.solve(information, gradient)), 0.0))

    def _shrink(
        self, optimum: tuple[Any, ...], replicates: int
    ) -> list[dict[str, tuple[float, float]]]:
        """For each test, each quantity's linear half-width with the test over without it
        (≤ 1), and the half-width with it in its declared scale — from the measured curves'
        Jacobian at the optimum and the test's curve sensitivities there (``optimum``:
        :meth:`_linearised` there): ``{name: (ratio, half)}``."""
        _, data, _, sensitivity, gradients = optimum
        before = self._information(data, None, replicates)
        out = []
        for k in range(sensitivity.shape[0]):
            after = self._information(data, sensitivity[k], replicates)
            entry = {}
            for name, g in gradients.items():
                now, then = self._half(before, g), self._half(after, g)
                entry[name] = (min(then / now, 1.0) if now > 0 else 1.0, then)
            out.append(entry)
        return out

    def _at_open_sides(
        self,
        alternatives: list[dict[str, Any]],
        tests: list[dict[str, Any]],
        optimum: np.ndarray,
        replicates: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """At each open side's re-fit (alternatives, tests; NaN for a closed side, whose
        shrink is the optimum's information): ``χ²_refit`` of
        :func:`~._information.refit_chi2`, what each test adds there once the other
        parameters re-fit to it too (``optimum``: the optimum's curves at the tests); and the
        linear half-width of the side's quantity there with the test (inf where the test
        narrows it by less than ``SEEN_SHARE``: it sees nothing of it there) — the test
        closes the side only if it sees the quantity where the
        side ends, not only at today's optimum (a thicker coat's curves at 5 mm reach no
        plateau where today's coat does: the one test tells nothing of how large its Mp
        may be)."""
        refit = np.full((len(alternatives), len(tests)), np.nan)
        far = refit.copy()
        sides = [
            k
            for k, alt in enumerate(alternatives)
            if self.entries[alt["quantity"]][alt["side"]] is None
        ]
        if not sides:
            return refit, far
        at = self._linearised([alternatives[k]["params"] for k in sides], tests)
        for k, (x, data, curves, sensitivity, gradients) in zip(sides, at, strict=True):
            g = gradients[alternatives[k]["quantity"]]
            without = self._half(self._information(data, None, replicates), g)
            for t in range(len(tests)):
                difference = curves[t] - optimum[t]
                if not np.all(np.isfinite(difference)):
                    continue
                refit[k, t] = refit_chi2(
                    data, sensitivity[t], difference, g, (-x, 1.0 - x), self.noise, replicates
                )
                with_test = self._half(self._information(data, sensitivity[t], replicates), g)
                seen = with_test < (1.0 - SEEN_SHARE) * without
                far[k, t] = with_test if seen else math.inf
        return refit, far

    def _predicted(
        self,
        curves: np.ndarray,
        alternatives: list[dict[str, Any]],
        shrink: dict[str, tuple[float, float]],
        far: np.ndarray,
        refit: np.ndarray,
    ) -> dict[str, dict[str, Any]]:
        """Every quantity's interval after the test whose curves (1 + alternatives, A) are
        given. A closed side shrinks by the test's information at the optimum (the linear
        half-width with it over without it, ``shrink``); an open side closes where the
        test rules out its re-fit at the range's end — what it adds there, once the other
        parameters re-fit to it too (``refit``), lifts it over the threshold
        (:func:`~._information.moved_side`) — at the linear half-width with the
        test (a quadratic rise from the optimum to that re-fit would promise more than a
        yield onset, a threshold, gives)."""
        at = {(a["quantity"], a["side"]): k for k, a in enumerate(alternatives, start=1)}
        out: dict[str, dict[str, Any]] = {}
        for name, quantity in self.quantities.items():
            entry = self.entries[name]
            q0 = quantity.scale(entry["value"])
            ends: dict[str, float | None] = {}
            for side, sign in (("low", -1.0), ("high", 1.0)):
                end = entry[side]
                size = None if end is None else abs(quantity.scale(end) - q0)
                k = at.get((name, side))
                ratio_info, half_after = shrink[name]
                if size is not None:
                    size *= ratio_info
                elif k is not None and np.all(np.isfinite(curves[k])):
                    reach = self._reach(quantity, q0, alternatives[k - 1])
                    if self._moves(alternatives[k - 1], reach, refit[k - 1], far[k - 1]):
                        size = min(reach, max(half_after, far[k - 1]))
                ends[side] = None if size is None else end_value(quantity, q0, sign, size)
            now = _width(quantity, entry["low"], entry["high"])
            after = _width(quantity, ends["low"], ends["high"])
            out[name] = {
                "value": entry["value"],
                "low": ends["low"],
                "high": ends["high"],
                "kind": _kind(ends["low"], ends["high"]),
                "width_now": now,
                "width_after": min(after, now),
            }
            out[name]["precision"] = precision_words(quantity, out[name])
        return out

    def _params(self, alternative: Mapping[str, Any]) -> np.ndarray:
        return np.array([alternative["params"][n] for n in self.problem.space.names])

    def _reach(self, quantity: Any, q0: float, alternative: Mapping[str, Any]) -> float:
        """How far (declared scale) from today's fit ``q0`` a side's re-fit lies."""
        return abs(quantity.scaled(self._params(alternative)) - q0)

    def _moves(
        self, alternative: Mapping[str, Any], reach: float, chi2: float, far: float
    ) -> bool | None:
        """Whether a test moves an open side in: None where it does not see the quantity at
        the side's re-fit (``far`` not under ``reach``; NaN, a failed run, is not seen), else
        whether what it adds there once the other parameters re-fit (``chi2``, of
        :func:`~._information.refit_chi2`) lifts the re-fit over the threshold
        (:func:`~._information.moved_side`)."""
        if not far < reach:
            return None
        ratio = 0.0 if alternative["ratio"] is None else max(float(alternative["ratio"]), 0.0)
        return moved_side(reach, ratio, float(chi2), self.threshold) is not None

    def _left_open(
        self,
        predicted: list[dict[str, dict[str, Any]]],
        alternatives: list[dict[str, Any]],
        refit: np.ndarray,
        far: np.ndarray,
        shrink: list[dict[str, tuple[float, float]]],
        tests: list[dict[str, Any]],
    ) -> list[dict[str, Any]]:
        """The quantities with an open side no candidate is predicted to close
        (``predicted``, ``shrink``: every test's, the reference's last; ``refit``, ``far``:
        :meth:`_at_open_sides`'s), each with why, side by side (``reasons``, keys of
        :data:`LEFT_OPEN`), as :meth:`_predicted` decided it: at the side's re-fit (where
        the profile ended it, at a range's end) no candidate sees the quantity —
        ``near_fit`` where one settles it near today's fit (``near_fit``: the candidate
        that narrows its linear interval most there), ``insensitive`` where none does; a
        candidate sees it there but the other parameters re-fit to it at that value
        (``absorbed``); or one moves the side in, not off the range's end (``range_end``).
        ``ends``: the quantity at each side's re-fit."""
        at = {(a["quantity"], a["side"]): k for k, a in enumerate(alternatives)}
        found = []
        for name, quantity in self.quantities.items():
            entry = self.entries[name]
            sides = [
                side
                for side in ("low", "high")
                if entry[side] is None and all(p[name][side] is None for p in predicted)
            ]
            if not sides:
                continue
            q0 = quantity.scale(entry["value"])
            best = min(range(len(tests) - 1), key=lambda t: shrink[t][name][0])
            near = shrink[best][name][0] < SETTLES
            reasons, ends = {}, {}
            for side in sides:
                k = at.get((name, side))
                if k is None:
                    reasons[side] = "no re-fit"
                    continue
                alt = alternatives[k]
                ends[side] = quantity.value(self._params(alt))
                reach = self._reach(quantity, q0, alt)
                moves = [self._moves(alt, reach, refit[k, t], far[k, t]) for t in range(len(tests))]
                if any(moves):
                    reasons[side] = "range_end"
                elif any(m is not None for m in moves):
                    reasons[side] = "absorbed"
                else:
                    reasons[side] = "near_fit" if near else "insensitive"
            found.append(
                {
                    "quantity": name,
                    "kind": entry["kind"],
                    "now": _interval_words(entry),
                    "sides": sides,
                    "ends": ends,
                    "reasons": reasons,
                    "near_fit": as_json(tests[best]) if "near_fit" in reasons.values() else None,
                }
            )
        return found

    def _default_goal(self, predicted: list[dict[str, dict[str, Any]]]) -> str | None:
        """The least determined quantity (the widest share of its range) some candidate
        settles (cuts its width by ``1 − SETTLES``), or None."""
        settled = [
            name
            for name in self.quantities
            if any(p[name]["width_after"] < SETTLES * p[name]["width_now"] for p in predicted)
        ]
        if not settled:
            return None
        span = {n: abs(float(np.diff(q.range_scaled)[0])) for n, q in self.quantities.items()}
        return max(settled, key=lambda n: predicted[0][n]["width_now"] / span[n])

    def _entry(
        self,
        test: Mapping[str, Any],
        predicted: dict[str, dict[str, Any]],
        goal: str | None,
        pairs: list[tuple[str, str]],
        pair_curves: dict[tuple[str, str], np.ndarray],
        k: int,
    ) -> dict[str, Any]:
        r = self.design.replicates
        separates = [
            list(pair)
            for pair in pairs
            if pair in pair_curves
            and separated(pair_curves[pair][0, k], pair_curves[pair][1, k], self.noise, r)
        ]
        return {
            "conditions": as_json(test),
            "replicates": r,
            "goal": goal,
            "predicted": predicted,
            "settles": [
                n for n, p in predicted.items() if p["width_after"] < SETTLES * p["width_now"]
            ],
            "separates": separates,
        }

    # -- discrimination and testability --------------------------------------------------------
    def _pairs(
        self, diagnosis: Mapping[str, Any] | None, tests: list[dict[str, Any]]
    ) -> tuple[list[tuple[str, str]], dict[tuple[str, str], np.ndarray]]:
        """The pairs of effects to tell apart (the leader and those tied with it, else the
        leader and the runner-up) and their fits' curves at every candidate (2, T, A)."""
        if not diagnosis or not diagnosis.get("systematic") or not diagnosis.get("ranking"):
            return [], {}
        ranking = diagnosis["ranking"]
        leaders = [ranking[0]["effect"], *diagnosis.get("tied_with", [])]
        if len(leaders) < 2 and len(ranking) > 1:
            leaders.append(ranking[1]["effect"])
        by_effect = {e["effect"]: e for e in ranking}
        pairs = [(a, b) for i, a in enumerate(leaders) for b in leaders[i + 1 :]]
        base = tuple(self.problem.effects)
        curves = {}
        for a, b in pairs:
            fits = [((*base, a), by_effect[a]["params"]), ((*base, b), by_effect[b]["params"])]
            curves[(a, b)] = self.curves(fits, tests)
        return pairs, curves

    def _inseparable(
        self,
        pairs: list[tuple[str, str]],
        pair_curves: dict[tuple[str, str], np.ndarray],
        tests: list[dict[str, Any]],
    ) -> list[dict[str, Any]]:
        r, found = self.design.replicates, []
        for pair in pairs:
            a, b = pair_curves[pair][0], pair_curves[pair][1]
            squares = (a - b) ** 2
            rms = np.sqrt(np.where(np.isnan(squares), 0.0, squares).mean(axis=1))
            if any(separated(a[k], b[k], self.noise, r) for k in range(len(tests))):
                continue
            k = int(np.nanargmax(rms))
            found.append(
                {
                    "effects": list(pair),
                    "largest_difference_n": float(rms[k]),
                    "at": as_json(tests[k]),
                    "reason": (
                        f"no test inside [design] separates `{pair[0]}` and `{pair[1]}` by "
                        f"two noise levels: their calibrated curves differ by {rms[k]:.2g} N "
                        f"RMS at most ({conditions_text(tests[k], self.design.conditions)}), "
                        f"noise {self.noise:.2g} N"
                    ),
                }
            )
        return found

    def _untestable(self) -> list[dict[str, Any]]:
        """Effects whose every condition is constant in the measurements, with the test
        that would vary it."""
        table = self.problem.data.tests
        found = []
        for name in available_effects():
            if name in self.problem.effects:
                continue
            reads = [c for c in get_effect(name).reads if c != "width_mm"]
            if not reads or any(c in table and table[c].nunique() > 1 for c in reads):
                continue
            condition = reads[0]
            present = condition in table
            value = table[condition].iloc[0] if present else UNRECORDED.get(condition)
            seen = f"always {value}" if present else f"not recorded: {value} in every test"
            found.append(
                {
                    "effect": name,
                    "reason": f"{condition} never varies in the data ({seen})",
                    "test": self._varying(condition, value),
                }
            )
        return found

    def _varying(self, condition: str, value: Any) -> dict[str, Any] | str:
        """A test inside ``[design]`` at another value of ``condition``, or what to add."""
        for r in self.design.ranges:
            if r.name == condition:
                far = (
                    r.high if value is None or abs(r.high - value) >= abs(r.low - value) else r.low
                )
                return as_json({**self.reference, condition: far})
        for name, choices in self.design.choices.items():
            if name == condition:
                other = [c for c in choices if c != value]
                if other:
                    return as_json({**self.reference, condition: other[0]})
        return f"add {condition} to [design]: the lab must vary it for the data to test it"

    # -- output ----------------------------------------------------------------------------------
    def _message(
        self,
        goal: str | None,
        recommended: list[dict[str, Any]],
        reference: dict[str, Any],
        untestable: list[dict[str, Any]],
        inseparable: list[dict[str, Any]],
        left_open: list[dict[str, Any]],
    ) -> str:
        varied = self.design.conditions
        if goal is None or not recommended:
            text = "no test inside [design] settles what the data leave open"
        else:
            best = recommended[0]
            now, after = self.entries[goal], best["predicted"][goal]
            again = reference["predicted"][goal]
            others = [n for n in best["settles"] if n != goal]
            text = (
                f"next test: {conditions_text(best['conditions'], varied)} "
                f"({best['replicates']} replicates) settles {goal} to "
                f"{after['precision']} (95 %; now {_interval_words(now)}; "
                f"{best['replicates']} more of the reference test: {again['precision']})"
                + (f", and narrows {', '.join(others)}" if others else "")
            )
        for reason, words in LEFT_OPEN.items():
            named = [
                _side_words(item, reason)
                for item in left_open
                if reason in item["reasons"].values()
            ]
            if named:
                text += f"; {', '.join(named)} — each: {words}"
        for item in untestable:
            test = item["test"]
            how = test if isinstance(test, str) else f"a test at {conditions_text(test)}"
            text += f"; `{item['effect']}` cannot be tested: {item['reason']} — {how}"
        for item in inseparable:
            text += "; " + item["reason"]
        return text

    def _figure(
        self,
        test: Mapping[str, Any],
        curves: np.ndarray,
        alternatives: list[dict[str, Any]],
        goal: str | None,
        output_dir: str | Path | bool | None,
    ) -> str | None:
        """The calibrated curve and the goal's alternative fits at the recommended test,
        with a band of two noise levels over its replicates' mean (PNG)."""
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            return None
        spec = self.problem.spec
        folder = Path(output_dir) if isinstance(output_dir, str | Path) else spec.directory
        angle = self.problem.angle_deg
        band = 2 * self.noise / math.sqrt(self.design.replicates)
        figure, axis = plt.subplots(figsize=(7, 4))
        axis.fill_between(
            angle,
            curves[0] - band,
            curves[0] + band,
            color="grey",
            alpha=0.3,
            label="calibrated ± 2 noise (mean of the replicates)",
        )
        axis.plot(angle, curves[0], "k-", label="calibrated")
        for k, alt in enumerate(alternatives, start=1):
            if alt["quantity"] == goal:
                axis.plot(angle, curves[k], "--", label=f"{goal} at its {alt['side']} end")
        axis.set(
            xlabel="rotation [deg]",
            ylabel="force [N]",
            title=f"Next test: {conditions_text(test, self.design.conditions)}",
        )
        axis.legend(fontsize=8)
        figure.tight_layout()
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{spec.name}-next-test.png"
        figure.savefig(path, dpi=110)
        plt.close(figure)
        return str(path)


def _width(quantity: Any, low: float | None, high: float | None) -> float:
    """An interval's width in the quantity's declared scale (an open side: to the range)."""
    range_low, range_high = quantity.range_scaled
    a = range_low if low is None else quantity.scale(low)
    b = range_high if high is None else quantity.scale(high)
    return max(b - a, 0.0)


def _kind(low: float | None, high: float | None) -> str:
    from ..calibration._determination import interval_kind_of

    return interval_kind_of(low is not None, high is not None)


def precision_words(quantity: Any, entry: Mapping[str, Any]) -> str:
    """A predicted interval by its width, not its place (the test decides where it lies):
    ``±0.04 %`` of a log-scaled quantity, ``±0.002`` of a linear one; a one-sided bound or
    free where a side stays open."""
    if entry["low"] is None or entry["high"] is None:
        return _interval_words(entry) + (" only" if entry["low"] or entry["high"] else "")
    half = entry["width_after"] / 2
    return f"±{100 * math.expm1(half):.2g} %" if quantity.log else f"±{half:.3g}"


def _side_words(item: Mapping[str, Any], reason: str) -> str:
    """A quantity left open, in words, for the sides of it whose reason is ``reason``: the
    quantity and today's interval where every such side has it, else the side."""
    sides = [side for side, why in item["reasons"].items() if why == reason]
    if len(sides) == len(item["sides"]):
        return f"{item['quantity']} ({'free' if item['kind'] == 'free' else item['now']})"
    return f"{item['quantity']}'s {'upper' if sides[0] == 'high' else 'lower'} side"


def _interval_words(entry: Mapping[str, Any]) -> str:
    low, high = entry["low"], entry["high"]
    if low is not None and high is not None:
        return f"{low:.4g} – {high:.4g}"
    if low is not None:
        return f"≥ {low:.4g}"
    if high is not None:
        return f"≤ {high:.4g}"
    return "free within its range"


def _diagnosis(url: str, name: str) -> dict[str, Any] | None:
    """The calibration study's stored diagnosis, if any."""
    try:
        study = optuna.load_study(study_name=name, storage=open_storage(url))
    except KeyError:
        return None
    return study.user_attrs.get("diagnosis")


def _record(
    url: str, name: str, result: NextTestResult, stored: Mapping[str, Any], data_sha: str
) -> None:
    """The recommendation as the calibration study's ``next_test`` attribute (with the
    data it was made on: the calibration that sees its test states predicted against
    realised) and the dashboard note."""
    quiet_optuna()
    study = optuna.load_study(study_name=name, storage=open_storage(url))
    record = {**json.loads(json.dumps(result.to_json())), "data_sha256": data_sha}
    study.set_user_attr("next_test", record)
    try:
        from optuna_dashboard import save_note
    except ImportError:
        return
    lines = [f"## Next test: {result.message}", ""]
    if result.recommended:
        lines += ["| test | replicates | settles |", "|---|---|---|"]
        for entry in result.recommended:
            text = conditions_text(entry["conditions"])
            lines.append(
                f"| {text} | {entry['replicates']} | {', '.join(entry['settles']) or '—'} |"
            )
    save_note(study, "\n".join([*lines, "", *calibration_note(stored)]))
