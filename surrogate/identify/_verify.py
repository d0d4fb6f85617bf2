"""The verify study: full-solver runs of the main job as trials of ``<name>/verify``.

One module for every rule of that study, used alike by the in-process verifier
(:class:`Verifier`, ``surrogate run --jobs 1``) and by the workers
(:mod:`surrogate.identify._worker`, ``--jobs N`` and ``surrogate worker``):

- :func:`verification_inputs`: what a verification solves and hashes — the
  point, the rig, the solver *and its settings* (mesh, command, timeout,
  template …), so a worker and the planner agree on every run's identity;
- :func:`open_verify_study` (created with its attributes when new) and
  :func:`as_planned` (a worker's study file must match the plan);
- :func:`enqueue` (a point becomes a ``WAITING`` trial carrying its input hash,
  phase and plan), :func:`tell_verification` (a result finishes its trial),
  :func:`record_of` (a finished trial read back) and :func:`finished_records`.

A trial holds the params, the relative F60 misfit as value, the constraint
values (``≤ 0`` feasible), F60, θsat and the curve.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np
import optuna
from optuna.trial import FrozenTrial, TrialState

from .._errors import InputDataError
from ..solvers._base import result_settings
from ..solvers._batch import solve_inputs, solver_inputs
from ..solvers._cache import ResultCache, input_hash
from ..storage._dashboard import attach_run_report
from ..storage._optuna import quiet_optuna, suggest
from ..storage._storage import MAX_RETRY, Patience, open_storage, retry_callback, storage_errors
from ..study._spec import StudySpec, Targets
from ._objective import (
    constraint_values,
    is_feasible,
    meets_target,
    refuse_model_effects,
    relative_misfit,
)

if TYPE_CHECKING:  # pandas loads with the surrogate's training set, not in a worker
    from ..study._samples import SampleSet

__all__ = [
    "METRIC",
    "VERIFY",
    "Queue",
    "Verification",
    "Verifier",
    "as_planned",
    "enqueue",
    "finished_records",
    "open_verify_study",
    "plan_of",
    "record_of",
    "target_of",
    "tell_verification",
    "verification_inputs",
    "verify_study_name",
]

logger = logging.getLogger(__name__)

METRIC = "f60_relative_misfit"


@dataclass(frozen=True)
class Verification:
    """One full-solver run of the verify study, as its trial holds it.

    ``status`` is ``ok`` or ``failed`` (then ``reason`` says why and the other
    fields keep their defaults); ``misfit`` is ``|F60 / target − 1|``,
    ``constraints`` the named constraint values (``≤ 0`` feasible), ``number``
    the trial's number, ``angle_deg``/``force_n`` the curve.
    """

    params: dict[str, float]
    status: str
    reason: str = ""
    f60_n: float = math.nan
    theta_sat_deg: float = math.nan
    saturated: bool = False
    misfit: float = math.inf
    constraints: dict[str, float] = field(default_factory=dict)
    number: int | None = None
    angle_deg: list[float] = field(default_factory=list)
    force_n: list[float] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


_T = TypeVar("_T")


class Dispatch(Protocol):
    """Verifies a batch of points through the storage's workers
    (:class:`surrogate.identify._worker.WorkerDispatcher`)."""

    patience: Patience  # rides out a database that cannot be reached for a while

    def __call__(
        self, study: optuna.Study, points: list[dict[str, float]], phase: str
    ) -> dict[str, Verification]: ...


class Queue(Protocol):
    """The rules of one queue study that the worker loop and the dispatcher follow
    (:mod:`surrogate.identify._worker`): the verify study's (:data:`VERIFY`) and the run
    queue's (:data:`surrogate.identify._runs.RUNS`). A record has ``ok`` and ``reason``."""

    name: str

    def study_name(self, spec: StudySpec) -> str: ...

    def check(self, spec: StudySpec) -> None: ...

    def planned(self, spec: StudySpec, attrs: Mapping[str, Any]) -> StudySpec: ...

    def missing(self, spec: StudySpec, storage: str) -> str: ...

    def inputs(
        self, spec: StudySpec, trial: optuna.Trial
    ) -> tuple[dict[str, float], dict[str, Any]]: ...

    def enqueue(
        self, study: optuna.Study, spec: StudySpec, items: Any, phase: str
    ) -> list[str]: ...

    def tell(
        self,
        study: optuna.Study,
        trial: optuna.Trial,
        spec: StudySpec,
        params: dict[str, float],
        result: dict[str, Any],
    ) -> Any: ...

    def record_of(self, trial: FrozenTrial) -> Any: ...

    def finished(self, study: optuna.Study, keys: Iterable[str]) -> dict[str, Any]: ...

    def describe(self, record: Any) -> str: ...


def verify_study_name(spec: StudySpec) -> str:
    return f"{spec.name}/verify"


def target_of(spec: StudySpec) -> float:
    target = spec.targets.f60_n
    assert target is not None  # checked when the run starts
    return target


def plan_of(spec: StudySpec) -> str:
    """What makes the loop's decisions: its seed and its target.

    A planner started again on the same storage with the same plan replays it
    (:class:`Verifier`); runs of another plan are training data from the start.
    The space, the constraints, the preferences, the ``[budget]`` keys but the run
    limit and whether the built-in solver is the expensive one's prior are part of it
    (hashed), as they change the decisions.
    """
    drivers = json.dumps(
        [
            spec.space.to_dict(),
            {  # the run limit only says where the replay stops
                key: value
                for key, value in dataclasses.asdict(spec.budget).items()
                if key != "max_solver_calls"
            },
            list(spec.preference_order),
            dataclasses.asdict(spec.constraints),
            *([{"multi_fidelity": True}] if spec.low_fidelity else []),
        ],
        sort_keys=True,
        default=str,
    )
    digest = hashlib.sha256(drivers.encode()).hexdigest()[:12]
    return (
        f"seed {spec.seed}, target F60 {target_of(spec):g} N ± {spec.targets.tolerance:g}, "
        f"space/budget/preferences {digest}"
    )


def verification_inputs(spec: StudySpec, params: Mapping[str, float]) -> dict[str, Any]:
    """The solver inputs of one verification: point, rig, solver and its settings."""
    return solver_inputs(
        dict(params), spec.rig, solver=spec.solver, solver_settings=spec.solver_settings
    )


# -- the study --------------------------------------------------------------------------------
def plan_attributes(spec: StudySpec) -> dict[str, Any]:
    """The study attributes a planner writes and a worker checks its study file against."""
    return {
        "description": "full-solver verification runs of a coating identification "
        "(surrogate run); value = |F60/target - 1|, constraints <= 0 feasible",
        "objective": f"{METRIC} = |F60 / target - 1|",
        "target_f60_n": target_of(spec),
        "tolerance": spec.targets.tolerance,
        "constraints": [
            "theta_sat_min: theta_min - theta_sat [deg]",
            "tcoat_max: Tcoat - fraction*t [mm]",
        ],
        "parameters": spec.space.to_dict(),
        "solver": spec.solver,
        "solver_settings": result_settings(spec.solver, spec.solver_settings),
        "rig": spec.rig.to_dict(),
    }


def open_verify_study(spec: StudySpec, storage: str, *, heartbeat_s: int | None) -> optuna.Study:
    """The verify study for a planner (created if new), on a heartbeat-aware storage."""
    quiet_optuna()
    with storage_errors(storage):
        study = optuna.create_study(
            storage=open_storage(storage, heartbeat_s=heartbeat_s),
            study_name=verify_study_name(spec),
            direction="minimize",
            load_if_exists=True,
        )
        study.set_metric_names([METRIC])
        for key, value in plan_attributes(spec).items():
            if study.user_attrs.get(key) != value:
                study.set_user_attr(key, value)
    return study


def as_planned(spec: StudySpec, attrs: Mapping[str, Any]) -> StudySpec:
    """The study file with the plan's target; refuse a file that differs from the plan.

    The solver settings are part of every run's identity (:func:`verification_inputs`),
    so a worker with other settings would solve other runs than the ones queued.
    """
    for key, section, mine in (
        ("solver", "solver", spec.solver),
        ("solver_settings", "solver", result_settings(spec.solver, spec.solver_settings)),
        ("rig", "rig", spec.rig.to_dict()),
        ("parameters", "parameters", spec.space.to_dict()),
    ):
        if key in attrs and attrs[key] != mine:
            raise InputDataError(
                f"{spec.path}: its [{section}] differs from the plan in the storage"
                f"{_difference(attrs[key], mine)}; start the worker with the planner's study file"
            )
    target = attrs.get("target_f60_n", spec.targets.f60_n)
    tolerance = attrs.get("tolerance", spec.targets.tolerance)
    return replace(spec, targets=Targets(target, tolerance))


def _difference(planned: Any, mine: Any) -> str:
    """`` (mesh: 'coarse' planned, 'fine' here)`` for the first key that differs, if a table."""
    if not isinstance(planned, dict) or not isinstance(mine, dict):
        return f" ({planned!r} planned, {mine!r} here)"
    for key in sorted(set(planned) | set(mine)):
        if planned.get(key) != mine.get(key):
            return f" ({key}: {planned.get(key)!r} planned, {mine.get(key)!r} here)"
    return ""


# -- trials -----------------------------------------------------------------------------------
def enqueue(
    study: optuna.Study, spec: StudySpec, points: Iterable[Mapping[str, float]], *, phase: str
) -> list[str]:
    """Queue each point as a WAITING trial unless it is already queued, running or done.

    Returns the input hashes of ``points`` in order (one per point).
    """
    known = known_keys(study)
    keys = []
    for point in points:
        params = {name: float(point[name]) for name in spec.space.names}
        key = input_hash(verification_inputs(spec, params))
        if key not in known:
            study.enqueue_trial(params, user_attrs=_trial_attrs(spec, key, phase))
            known.add(key)
        keys.append(key)
    return keys


def known_keys(study: optuna.Study) -> set[str | None]:
    """The input hashes of the study's runs that are queued, running or done — every run
    but one abandoned (failed with no copy to come): what a queue does not queue again."""
    return {
        t.user_attrs.get("input_hash")
        for t in study.get_trials(deepcopy=False)
        if t.state != TrialState.FAIL or "reason" in t.user_attrs or retry_pending(t)
    }


def _trial_attrs(spec: StudySpec, key: str, phase: str) -> dict[str, str]:
    return {"input_hash": key, "phase": phase, "plan": plan_of(spec)}


def queue_lost_copies(study: optuna.Study, settled_s: float) -> None:
    """Queue the copy of a trial failed as stale whose copy was never queued.

    ``optuna.storages.fail_stale_trials`` fails a stale trial and then queues its copy,
    in two steps; a judge killed, or cut off from the storage, between them left a
    FAIL trial that :func:`retry_pending` counts on a copy that never came, and the
    planner waited for it for ever. Only trials failed more than ``settled_s`` ago are
    copied, so a judge still at work does not see its trial copied twice. (A copy names
    the trials it copies in ``retry_history``; a solver failure has a ``reason``.)
    """
    trials = study.get_trials(deepcopy=False)
    copied = {number for t in trials for number in t.system_attrs.get("retry_history", [])}
    now = datetime.datetime.now()  # the clock datetime_complete was written with
    for trial in trials:
        if (
            trial.state == TrialState.FAIL
            and "reason" not in trial.user_attrs
            and retry_pending(trial)
            and trial.number not in copied
            and trial.datetime_complete is not None
            and (now - trial.datetime_complete).total_seconds() > settled_s
        ):
            retry_callback()(study, trial)


def retry_pending(trial: FrozenTrial) -> bool:
    """An interrupted trial whose copy was queued again (see :func:`retry_callback`)."""
    return len(trial.system_attrs.get("retry_history", [])) + 1 <= MAX_RETRY


def tell_verification(
    study: optuna.Study,
    trial: optuna.Trial,
    spec: StudySpec,
    params: dict[str, float],
    result: dict[str, Any],
) -> Verification:
    """Finish ``trial`` with one full-solver ``result``; return the verifier's record.

    A failed run is a FAIL trial with its ``reason``; a successful one carries
    the misfit as value, the constraints (Optuna 5 and the list that
    optuna-dashboard 0.21 reads), F60, θsat and the curve.
    """
    if result["status"] != "ok":
        trial.set_user_attr("reason", result["reason"])
        study.tell(trial, state=TrialState.FAIL)
        return Verification(params, "failed", reason=result["reason"])
    misfit = relative_misfit(result["f60_n"], target_of(spec))
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
    return Verification(
        params,
        "ok",
        f60_n=result["f60_n"],
        theta_sat_deg=result["theta_sat_deg"],
        saturated=result["saturated"],
        misfit=misfit,
        constraints=constraints,
        number=trial.number,
        angle_deg=result["angle_deg"],
        force_n=result["force_n"],
    )


def record_of(trial: FrozenTrial) -> Verification:
    """The record :func:`tell_verification` returned, read back from a finished trial."""
    if trial.state != TrialState.COMPLETE:
        return Verification(dict(trial.params), "failed", reason=trial.user_attrs.get("reason", ""))
    attrs = trial.user_attrs
    return Verification(
        dict(trial.params),
        "ok",
        f60_n=attrs["f60_n"],
        theta_sat_deg=attrs["theta_sat_deg"],
        saturated=attrs["saturated"],
        misfit=float(trial.value if trial.value is not None else np.inf),
        constraints=dict(attrs["constraints"]),
        number=trial.number,
        angle_deg=attrs["curve_angle_deg"],
        force_n=attrs["curve_force_n"],
    )


def finished_records(
    study: optuna.Study,
    keys: Iterable[str],
    *,
    read: Callable[[FrozenTrial], Any] = record_of,
    lost: Callable[[FrozenTrial, str], Any] | None = None,
) -> dict[str, Any]:
    """The record of every key whose run is over (done, failed or abandoned): a finished
    trial ``read``, an abandoned run's ``lost`` (the verify study's records by default;
    the run queue's, :mod:`._runs`, are its own)."""
    wanted = set(keys)
    by_key: dict[str, list[FrozenTrial]] = {}
    for trial in study.get_trials(deepcopy=False):
        key = trial.user_attrs.get("input_hash")
        if key in wanted:
            by_key.setdefault(key, []).append(trial)
    records = {}
    for key, trials in by_key.items():
        done = [t for t in trials if t.state == TrialState.COMPLETE or "reason" in t.user_attrs]
        if done:
            records[key] = read(done[-1])
        elif all(t.state == TrialState.FAIL and not retry_pending(t) for t in trials):
            trial, reason = trials[-1], f"its worker died {MAX_RETRY + 1} times"
            records[key] = (
                lost(trial, reason)
                if lost is not None
                else Verification(dict(trial.params), "failed", reason=reason)
            )
    return records


class VerifyQueue:
    """The verify study's rules for the worker loop (:class:`surrogate.identify._worker.
    _Worker`) and the planner's dispatcher; the run queue's are
    :data:`surrogate.identify._runs.RUNS`."""

    name = "verify"

    def study_name(self, spec: StudySpec) -> str:
        return verify_study_name(spec)

    def check(self, spec: StudySpec) -> None:
        refuse_model_effects(spec, "surrogate worker")

    def planned(self, spec: StudySpec, attrs: Mapping[str, Any]) -> StudySpec:
        return as_planned(spec, attrs)

    def missing(self, spec: StudySpec, storage: str) -> str:
        return (
            f"no study {verify_study_name(spec)!r} in {storage}; plan it first: "
            f"surrogate run {spec.path} --storage {storage} --jobs 0"
        )

    def inputs(
        self, spec: StudySpec, trial: optuna.Trial
    ) -> tuple[dict[str, float], dict[str, Any]]:
        params = suggest(trial, spec.space)
        return params, verification_inputs(spec, params)

    def enqueue(
        self,
        study: optuna.Study,
        spec: StudySpec,
        items: Iterable[Mapping[str, float]],
        phase: str,
    ) -> list[str]:
        return enqueue(study, spec, items, phase=phase)

    def tell(
        self,
        study: optuna.Study,
        trial: optuna.Trial,
        spec: StudySpec,
        params: dict[str, float],
        result: dict[str, Any],
    ) -> Verification:
        return tell_verification(study, trial, spec, params, result)

    def record_of(self, trial: FrozenTrial) -> Verification:
        return record_of(trial)

    def finished(self, study: optuna.Study, keys: Iterable[str]) -> dict[str, Verification]:
        return finished_records(study, keys)

    def describe(self, record: Verification) -> str:
        if not record.ok:
            return f"failed: {record.reason}"
        return f"F60 {record.f60_n:.4g} N, misfit {100 * record.misfit:.2f} %"


VERIFY = VerifyQueue()


# -- the in-process verifier ------------------------------------------------------------------
class Verifier:
    """Runs points with the full solver as trials of the verify study; resumes.

    ``dispatch`` (set by ``run --jobs N≠1``) verifies batches through the
    storage's workers instead of this process; both paths name a run by the
    hash of :func:`verification_inputs`, so no run is solved twice.

    With ``replay`` (the planner), a planner started again (after Ctrl-C or
    SIGKILL) replays its plan (:func:`plan_of`): the finished runs of each phase
    become known when the loop reaches that phase, so every decision sees what it saw the first time
    and proposes the same points; a phase's points queued by the earlier planner
    stay in the phase even if the proposal differs. Runs of another plan (an
    earlier seed or target) are known from the start; without ``replay`` (a
    reader such as ``export``) every finished run is.
    """

    def __init__(
        self,
        spec: StudySpec,
        study: optuna.Study,
        *,
        progress: bool,
        dispatch: Dispatch | None = None,
        replay: bool = False,
    ) -> None:
        self.spec = spec
        self.study = study
        self.progress = progress
        self.dispatch = dispatch
        self.cache = ResultCache(spec.directory / ".solver-cache")
        self.names = list(spec.space.names)
        self.records: dict[str, Verification] = {}
        self._replay: dict[str, Verification] = {}  # this plan's finished runs, not reached yet
        self._queued: dict[str, list[dict[str, float]]] = {}  # this plan's points by phase
        plan = plan_of(spec) if replay else None
        mine: set[str] = set()
        for trial in study.get_trials(deepcopy=False):
            key, attrs = trial.user_attrs.get("input_hash"), trial.user_attrs
            if key is not None and plan is not None and attrs.get("plan") == plan:
                mine.add(key)  # a queued point is held apart from the params until claimed
                point = trial.system_attrs.get("fixed_params") or trial.params
                self._queued.setdefault(attrs.get("phase", ""), []).append(dict(point))
        keys = {t.user_attrs.get("input_hash") for t in study.get_trials(deepcopy=False)}
        for key, record in finished_records(study, {k for k in keys if k is not None}).items():
            known = self._replay if key in mine else self.records
            known[key] = self._rescored(record)

    def _rescored(self, record: Verification) -> Verification:
        """A stored run judged against this study's target and constraints (a run of
        an earlier target keeps its F60, not its misfit)."""
        if not record.ok or self.spec.targets.f60_n is None:
            return record
        return replace(
            record,
            misfit=relative_misfit(record.f60_n, target_of(self.spec)),
            constraints=constraint_values(record.params, record.theta_sat_deg, self.spec),
        )

    def finish(self) -> None:
        """Count this plan's finished runs the loop did not reach (a smaller budget)."""
        self.records.update(self._replay)
        self._replay.clear()

    def patient(self, step: Callable[[], _T]) -> _T:
        """``step``, a storage write safe to repeat: where workers share the storage, it
        rides out a database that cannot be reached for a while, as they do."""
        return step() if self.dispatch is None else self.dispatch.patience(step)

    def publish(self, result: Mapping[str, Any], *, chosen_number: int | None, note: str) -> None:
        """The run's result as the verify study's attribute (what ``surrogate report``
        reads back), and the dashboard's figure of the verified curves and its note."""
        self.patient(lambda: self.study.set_user_attr("result", dict(result)))
        self.patient(
            lambda: attach_run_report(
                self.study,
                target_n=target_of(self.spec),
                tolerance=self.spec.targets.tolerance,
                records=list(self.records.values()),
                chosen_number=chosen_number,
                note=note,
            )
        )

    @property
    def calls(self) -> int:
        return len(self.records)

    def points(self) -> np.ndarray:
        return np.array([[r.params[n] for n in self.names] for r in self.records.values()])

    def verify(self, points: np.ndarray, *, phase: str) -> None:
        """Verify ``points`` in order while the budget lasts."""
        batch = self._with_queued(
            [dict(zip(self.names, map(float, p), strict=True)) for p in np.atleast_2d(points)],
            phase,
        )
        if self.dispatch is not None:
            room = max(self.spec.budget.max_solver_calls - self.calls, 0)
            found = self.dispatch(self.study, batch[:room], phase)
            for params in batch[:room]:  # in the batch's order, whoever finished first
                key = self._key(params)
                if key in found:
                    self._replay.pop(key, None)
                    self.records.setdefault(key, found[key])
        for params in batch:
            if self.calls >= self.spec.budget.max_solver_calls:
                break
            self.solve(params, phase=phase)
        self._report(phase)

    def _with_queued(self, batch: list[dict[str, float]], phase: str) -> list[dict[str, float]]:
        """``batch`` after the points an earlier planner queued for ``phase`` that
        it lacks (none when the plan replays exactly, the usual case)."""
        mine = {self._key(params) for params in batch}
        earlier = {}
        for params in self._queued.pop(phase, []):
            key = self._key(params)
            if key not in mine and key not in self.records:
                earlier[key] = params
        return [*earlier.values(), *batch]

    def _key(self, params: Mapping[str, float]) -> str:
        return input_hash(verification_inputs(self.spec, params))

    def record(self, params: Mapping[str, float]) -> Verification | None:
        """The record of the run at ``params``, if it is done."""
        return self.records.get(self._key(params))

    def solve(self, params: dict[str, float], *, phase: str) -> Verification:
        """One full-solver run as a trial; a finished run is never repeated."""
        inputs = verification_inputs(self.spec, params)
        key = input_hash(inputs)
        if key not in self.records and key in self._replay:
            self.records[key] = self._replay.pop(key)
        if key not in self.records and self.dispatch is not None:
            self.records.update(self.dispatch(self.study, [params], phase))
        if key not in self.records:
            result = self.cache.get(key)
            if result is None:
                result = solve_inputs(inputs)
                self.cache.put(key, inputs, result)
            self.records[key] = self._tell(params, key, result, phase)
        return self.records[key]

    def sensitivities(self, point: Verification) -> np.ndarray | None:
        """``∂ log F60 / ∂ log p`` at a verified point, by forward differences of
        the full solver (one run per parameter, +5 % each); None if the budget
        allows none (``[budget] identifiability_runs``)."""
        if self.spec.budget.identifiability_runs < len(self.names):
            return None
        step = np.log(1.05)
        gradient = np.empty(len(self.names))
        for k, name in enumerate(self.names):
            spec = self.spec.space[name]
            direction = 1.0 if point.params[name] * 1.05 <= spec.high else -1.0
            shifted = {**point.params, name: point.params[name] * np.exp(direction * step)}
            record = self.solve(shifted, phase="identifiability")
            if not record.ok:
                return None
            gradient[k] = direction * np.log(record.f60_n / point.f60_n) / step
        return gradient

    def _tell(
        self, params: dict[str, float], key: str, result: dict[str, Any], phase: str
    ) -> Verification:
        # queued with its hash and phase (as enqueue() queues a worker's trial), unless an
        # earlier planner queued it; claimed by its id, never by ask() (the oldest WAITING)
        if self._waiting(key) is None:
            self.study.enqueue_trial(
                params, user_attrs=_trial_attrs(self.spec, key, phase), skip_if_exists=False
            )
        trial_id = self._waiting(key)
        assert trial_id is not None
        storage = self.study._storage
        storage.set_trial_state_values(trial_id, state=TrialState.RUNNING)
        trial = optuna.Trial(self.study, trial_id)
        suggest(trial, self.spec.space)
        return tell_verification(self.study, trial, self.spec, params, result)

    def _waiting(self, key: str) -> int | None:
        for trial in self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            if trial.user_attrs.get("input_hash") == key:
                return trial._trial_id
        return None

    def meeting(self) -> list[Verification]:
        tolerance = self.spec.targets.tolerance
        return [
            r
            for r in self.records.values()
            if r.ok and meets_target(r.misfit, r.constraints, tolerance)
        ]

    def chosen(self) -> Verification | None:
        """The preferred verified point that meets the target, if any."""
        meeting = self.meeting()
        if not meeting:
            return None
        order = self.spec.preference_order
        return min(meeting, key=lambda r: tuple(r.params[name] for name in order))

    def best(self) -> Verification | None:
        ok = [r for r in self.records.values() if r.ok]
        if not ok:
            return None
        return min(ok, key=lambda r: (not is_feasible(r.constraints), r.misfit))

    def sample_set(self) -> SampleSet:
        """The verified runs as the surrogate's training set."""
        import pandas as pd

        from ..study._samples import SampleSet

        rows = [r for r in self.records.values() if r.ok]
        if len(rows) < 3:
            raise InputDataError(
                f"only {len(rows)} solver runs succeeded; the surrogate needs "
                "3 — check the parameter ranges"
            )
        runs = pd.DataFrame(
            {
                "run_id": np.arange(1, len(rows) + 1),
                **{n: [r.params[n] for r in rows] for n in self.names},
                "f60_n": [r.f60_n for r in rows],
                "theta_sat_deg": [r.theta_sat_deg for r in rows],
                "status": "ok",
            }
        )
        curves = pd.concat(
            [
                pd.DataFrame({"run_id": i + 1, "angle_deg": r.angle_deg, "force_n": r.force_n})
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
                f"best verified misfit {100 * best.misfit:.2f} %"
                + ("" if is_feasible(best.constraints) else " (infeasible)")
            )
        )
        met = " — target met" if self.chosen() is not None else ""
        logger.info(
            "[%s] %s: %d/%d solver calls, %s%s",
            self.spec.name,
            phase,
            self.calls,
            self.spec.budget.max_solver_calls,
            text,
            met,
        )
