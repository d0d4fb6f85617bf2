"""The run queue: ``calibrate``'s and ``diagnose``'s expensive runs as trials of
``<name>/runs``, solved by a launcher's worker jobs (``--launcher``).

The calibration names a run by the hash of its solver inputs — the coating, the
model's effect values, the test's conditions, the rig and the solver with its settings
(:func:`surrogate.solvers._batch.solver_inputs`). A queued trial holds the coating as
its params and the effects and conditions as attributes; a worker rebuilds the inputs
from them and *its own* study file (so the solver command it runs is its own, never
one read from the storage), refuses a run whose hash differs, solves it through the
result cache and tells the trial with the whole result (``result``); the planner reads
it back into its cache. Heartbeats, retries, "never lost, never solved twice" are the
verify study's (:mod:`._worker`): the same worker loop, another queue.

A trial's value is the run's F60 (0 where the curve has none); the study is a queue,
not a search (its direction means nothing).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from .._errors import InputDataError
from ..solvers._base import failed_result
from ..solvers._batch import solver_inputs
from ..solvers._cache import input_hash
from ..solvers._fidelity import LOW_FIDELITY
from ..storage._optuna import quiet_optuna, suggest
from ..storage._storage import STORAGE_PATIENCE_S, open_storage, storage_errors
from ..study._spec import StudySpec
from ._jobs import Launch, prepare_launch
from ._verify import finished_records, known_keys

__all__ = ["RUNS", "QueuedRuns", "RunRecord", "runs_study_name"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunRecord:
    """One finished run of the queue: its solver ``result`` (what ``solve_inputs``
    returns), ``ok`` and ``reason`` as the result says, the trial's ``number``."""

    params: dict[str, float]
    result: dict[str, Any] = field(default_factory=dict)
    number: int | None = None

    @property
    def ok(self) -> bool:
        return self.result.get("status") == "ok"

    @property
    def reason(self) -> str:
        return str(self.result.get("reason", ""))


def runs_study_name(spec: StudySpec) -> str:
    return f"{spec.name}/runs"


class RunQueue:
    """The run queue's rules for the worker loop (:class:`surrogate.identify._worker._Worker`)
    and the planner (:class:`QueuedRuns`); the verify study's are
    :data:`surrogate.identify._verify.VERIFY`."""

    name = "runs"

    def study_name(self, spec: StudySpec) -> str:
        return runs_study_name(spec)

    def check(self, spec: StudySpec) -> None:
        """Every study can queue runs (effects included)."""

    def planned(self, spec: StudySpec, attrs: Mapping[str, Any]) -> StudySpec:
        """The worker's own study file: a run it would name otherwise is refused by hash."""
        return spec

    def missing(self, spec: StudySpec, storage: str) -> str:
        return (
            f"no study {runs_study_name(spec)!r} in {storage}; it is made by "
            f"surrogate calibrate|diagnose {spec.path} --storage {storage} --launcher NAME"
        )

    def inputs(self, spec: StudySpec, trial: optuna.Trial) -> tuple[dict[str, float], dict]:
        """The coating (the trial's params) and the solver inputs the worker rebuilds."""
        params = suggest(trial, spec.space)
        attrs = trial.user_attrs
        inputs = solver_inputs(
            params,
            spec.rig,
            solver=spec.solver,
            effects=attrs.get("effects", {}),
            conditions=attrs.get("conditions", {}),
            solver_settings=spec.solver_settings,
        )
        return params, inputs

    def enqueue(
        self, study: optuna.Study, spec: StudySpec, items: Iterable[dict[str, Any]], phase: str
    ) -> list[str]:
        """Queue each solver input as a WAITING trial unless queued, running or done."""
        known = known_keys(study)
        keys = []
        for inputs in items:
            key = input_hash(inputs)
            if key not in known:
                attrs = {
                    "input_hash": key,
                    "phase": phase,
                    "effects": inputs["effects"],
                    "conditions": inputs["conditions"],
                }
                study.enqueue_trial(dict(inputs["params"]), user_attrs=attrs)
                known.add(key)
            keys.append(key)
        return keys

    def tell(
        self,
        study: optuna.Study,
        trial: optuna.Trial,
        spec: StudySpec,
        params: dict[str, float],
        result: dict[str, Any],
    ) -> RunRecord:
        trial.set_user_attr("result", result)
        if result["status"] != "ok":
            trial.set_user_attr("reason", result["reason"])
            study.tell(trial, state=TrialState.FAIL)
        else:
            f60 = float(result.get("f60_n", math.nan))
            study.tell(trial, f60 if math.isfinite(f60) else 0.0)
        return RunRecord(params, result, trial.number)

    def record_of(self, trial: FrozenTrial) -> RunRecord:
        return RunRecord(dict(trial.params), dict(trial.user_attrs.get("result", {})), trial.number)

    def lost(self, trial: FrozenTrial, reason: str) -> RunRecord:
        return RunRecord(dict(trial.params), failed_result(reason), trial.number)

    def finished(self, study: optuna.Study, keys: Iterable[str]) -> dict[str, RunRecord]:
        return finished_records(study, keys, read=self.record_of, lost=self.lost)

    def describe(self, record: RunRecord) -> str:
        if not record.ok:
            return f"failed: {record.reason}"
        return f"F60 {record.result.get('f60_n', math.nan):.4g} N"


RUNS = RunQueue()


def open_runs_study(spec: StudySpec, storage: str, *, heartbeat_s: int) -> optuna.Study:
    """The run queue of ``spec`` (created if new), on a heartbeat-aware storage."""
    quiet_optuna()
    with storage_errors(storage):
        study = optuna.create_study(
            storage=open_storage(storage, heartbeat_s=heartbeat_s),
            study_name=runs_study_name(spec),
            direction="minimize",
            load_if_exists=True,
        )
        study.set_metric_names(["f60_n"])
        description = "expensive solver runs of surrogate calibrate/diagnose (a queue)"
        if study.user_attrs.get("description") != description:
            study.set_user_attr("description", description)
    return study


class QueuedRuns:
    """A calibration's expensive runs through the run queue and a launcher's jobs.

    Called with a batch of solver inputs (a :class:`surrogate.calibration._loop.SolverRuns`
    batch), it queues them, keeps the launcher's jobs while they are open and yields
    ``(index, result)`` as :func:`surrogate._pool.imap_unordered` does. The queue study
    is opened at the first batch (a calibration refused before its first run writes
    nothing). A context manager: the jobs are cancelled on the way out, and SIGTERM
    stops the command (:class:`surrogate.cluster.Fleet`).
    """

    def __init__(
        self,
        spec: StudySpec,
        storage: str,
        launch: Launch,
        *,
        heartbeat_s: int,
        storage_patience_s: float = STORAGE_PATIENCE_S,
        progress: bool = True,
    ) -> None:
        self.spec, self.storage, self.launch = spec, storage, launch
        self.heartbeat_s, self.storage_patience_s = heartbeat_s, storage_patience_s
        self.progress = progress
        self._dispatch: Any = None
        self._study: optuna.Study | None = None

    def __enter__(self) -> QueuedRuns:
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._dispatch is not None:
            self._dispatch.fleet.__exit__(*exc)

    def __call__(self, batch: Sequence[dict[str, Any]]) -> Iterator[tuple[int, dict[str, Any]]]:
        dispatch, study = self._dispatcher()
        found = dispatch(study, list(batch), "calibration")
        for index, inputs in enumerate(batch):
            yield index, found[input_hash(inputs)].result

    def _dispatcher(self) -> tuple[Any, optuna.Study]:
        """The dispatcher and its fleet (entered) and the queue study, made at the first
        batch."""
        if self._dispatch is None or self._study is None:
            from ._worker import WorkerDispatcher

            dispatch = WorkerDispatcher(
                self.spec,
                self.storage,
                jobs=0,
                queue=RUNS,
                heartbeat_s=self.heartbeat_s,
                storage_patience_s=self.storage_patience_s,
                progress=self.progress,
            )
            study = open_runs_study(self.spec, self.storage, heartbeat_s=self.heartbeat_s)
            dispatch.fleet = self.launch.fleet(
                study,
                patience=dispatch.patience,
                heartbeat_s=self.heartbeat_s,
                progress=self.progress,
            )
            dispatch.fleet.__enter__()
            self._dispatch, self._study = dispatch, study
        return self._dispatch, self._study


def prepare_queued_runs(
    launcher: str,
    spec: StudySpec,
    storage: str,
    *,
    heartbeat_s: int,
    plugins: Sequence[str],
    progress: bool,
) -> QueuedRuns:
    """The run queue of a calibration with ``--launcher``, checked before anything is
    written: only an external solver's runs are worth a job each."""
    if spec.solver == LOW_FIDELITY:
        raise InputDataError(
            f"--launcher {launcher}: {spec.path}'s full solver is the built-in one, whose runs "
            "take milliseconds — a job each would cost far more than the run; drop "
            "--launcher, or set [solver] kind to an external solver (lsdyna, calculix)"
        )
    launch = prepare_launch(
        launcher,
        spec,
        storage,
        queue=RUNS.name,
        heartbeat_s=heartbeat_s,
        storage_patience_s=STORAGE_PATIENCE_S,
        plugins=plugins,
    )
    assert launch is not None
    return QueuedRuns(spec, storage, launch, heartbeat_s=heartbeat_s, progress=progress)
