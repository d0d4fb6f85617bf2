"""Batch evaluation of a design with the full solver: the run inputs, workers, cache, progress.

:func:`solver_inputs` is the one definition of a run's inputs (what its cache
key hashes); :func:`evaluate_design` runs a design through the package's one
process pool (:func:`surrogate._pool.imap_unordered`). pandas and tqdm load on
first use of :func:`evaluate_design`, so :func:`surrogate.simulate` stays light.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._errors import InputDataError
from .._pool import check_jobs, imap_unordered, one_blas_thread_within
from ..physics import SOLVER_VERSION
from ..study import COATING_PARAMETERS, ParameterSpace, Rig
from ._base import get_solver
from ._cache import ResultCache, input_hash

if TYPE_CHECKING:
    import pandas as pd

    from ..study import SampleSet

__all__ = ["evaluate_design", "solve_inputs", "solved", "solver_inputs", "solver_version"]

#: A batch of fewer built-in runs than this is solved in this process whatever ``jobs``
#: says: a run takes 2–10 ms, a pool of processes 30–150 ms to start and hand its results
#: back (2-core Xeon, 2026-12-02: 24 runs 58 ms in this process, 180 ms in two; the pool
#: first drew level at 200)
IN_PROCESS_RUNS = 200


def solver_inputs(
    point: dict[str, float],
    rig: Rig,
    *,
    solver: str = "builtin",
    effects: Mapping[str, Mapping[str, float]] | None = None,
    conditions: Mapping[str, Any] | None = None,
    solver_settings: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Everything that determines a run's result, as plain JSON data.

    ``effects`` maps effect names to their parameter values and ``conditions``
    holds the test's conditions (see :func:`surrogate.simulate`); both enter
    the input hash, so a run at other conditions is never taken from the cache.
    ``solver_settings`` (mesh, command, template, timeout, … of an external
    solver, see :mod:`surrogate.solvers`) are kept as ``inputs["solver_settings"]``
    (only when there are any); those that can change the result enter the hash
    (:func:`surrogate.solvers._base.run_identity`).
    """
    version = solver_version(solver)  # an unknown kind: the registry's one-line error
    missing = [name for name in COATING_PARAMETERS if name not in point]
    if missing:
        raise InputDataError(
            f"a solver run needs {', '.join(COATING_PARAMETERS)}; missing {', '.join(missing)}"
        )
    inputs: dict[str, Any] = {
        "solver": solver,
        "solver_version": version,
        "params": {name: float(point[name]) for name in COATING_PARAMETERS},
        "rig": rig.to_dict(),
        "effects": {
            name: {key: float(value) for key, value in sorted(values.items())}
            for name, values in sorted((effects or {}).items())
        },
        "conditions": {
            key: value if isinstance(value, str) else float(value)
            for key, value in sorted((conditions or {}).items())
        },
    }
    if solver_settings:
        inputs["solver_settings"] = dict(sorted(solver_settings.items()))
    return inputs


def solver_version(solver: str) -> str:
    """The version of solver ``solver`` that names its runs (a solver without one: the
    built-in rod's)."""
    return get_solver(solver).version or SOLVER_VERSION


def solve_inputs(inputs: dict[str, Any]) -> dict[str, Any]:
    """Run the solver named by ``inputs["solver"]`` (:func:`surrogate.solvers.get_solver`)
    on :func:`solver_inputs`; a failure is a result, not an exception."""
    return get_solver(inputs.get("solver", "builtin")).solve(inputs)


def solved(
    inputs: Sequence[dict[str, Any]],
    jobs: int,
    solve: Callable[[dict[str, Any]], dict[str, Any]] = solve_inputs,
) -> Iterator[tuple[int, dict[str, Any]]]:
    """``(index, solve(inputs[index]))`` for every run, in the order they finish: in ``jobs``
    processes (:func:`surrogate._pool.imap_unordered`), but in this process where the batch
    is fewer than :data:`IN_PROCESS_RUNS` runs of the built-in solver — under one BLAS thread,
    as in a child process, so the results are the same bits either way."""
    builtin = all(item.get("solver", "builtin") == "builtin" for item in inputs)
    if jobs > 1 and builtin and len(inputs) < IN_PROCESS_RUNS:
        return imap_unordered(one_blas_thread_within(solve), inputs, 1)
    return imap_unordered(solve, inputs, jobs)


def evaluate_design(
    design: pd.DataFrame,
    space: ParameterSpace,
    *,
    rig: Rig | None = None,
    solver: str = "builtin",
    solver_settings: Mapping[str, Any] | None = None,
    jobs: int = 1,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    meta: dict[str, Any] | None = None,
    solve: Callable[[dict[str, Any]], dict[str, Any]] = solve_inputs,
) -> SampleSet:
    """Run every point of ``design``; cached points are not solved again.

    Parameters
    ----------
    design : DataFrame
        One row per point with the columns of ``space`` (``case_id`` optional).
    jobs : int
        Worker processes (1 runs in this process).
    cache_dir : path, optional
        Result cache; every finished run is stored at once, so an interrupted
        batch resumes where it stopped.
    progress : bool
        Show a progress bar on stderr.
    """
    rig = Rig() if rig is None else rig
    check_jobs(jobs)
    cache = ResultCache(cache_dir) if cache_dir is not None else None
    inputs = [
        solver_inputs(point, rig, solver=solver, solver_settings=solver_settings)
        for point in design[list(space.names)].to_dict("records")
    ]
    keys = [input_hash(item) for item in inputs]
    results = _cached_results(cache, keys)
    calls = len(inputs) - len(results)
    _solve_missing(inputs, keys, results, cache=cache, solve=solve, jobs=jobs, progress=progress)
    provenance = {
        "solver": solver,
        "solver_version": solver_version(solver),
        "rig": rig.to_dict(),
        "solver_calls": calls,
        **(meta or {}),
    }
    return _sample_set(design, space, keys, [results[i] for i in range(len(inputs))], provenance)


def _cached_results(cache: ResultCache | None, keys: list[str]) -> dict[int, dict[str, Any]]:
    """The results already in ``cache``, by position in ``keys``."""
    if cache is None:
        return {}
    hits = {index: cache.get(key) for index, key in enumerate(keys)}
    return {index: hit for index, hit in hits.items() if hit is not None}


def _solve_missing(
    inputs: list[dict[str, Any]],
    keys: list[str],
    results: dict[int, dict[str, Any]],
    *,
    cache: ResultCache | None,
    solve: Callable[[dict[str, Any]], dict[str, Any]],
    jobs: int,
    progress: bool,
) -> None:
    """Solve the runs not yet in ``results`` in ``jobs`` processes, adding each to
    ``results`` and to the cache as it finishes, with a progress bar on stderr."""
    from tqdm import tqdm

    todo = [index for index in range(len(inputs)) if index not in results]
    bar = tqdm(
        total=len(inputs),
        initial=len(results),
        desc="solver runs",
        unit="run",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )
    try:
        for position, result in solved([inputs[i] for i in todo], jobs, solve):
            index = todo[position]
            results[index] = result
            if cache is not None:
                cache.put(keys[index], inputs[index], result)
            bar.update(1)
            bar.set_postfix(failed=sum(r["status"] != "ok" for r in results.values()))
    finally:
        bar.close()


def _sample_set(
    design: pd.DataFrame,
    space: ParameterSpace,
    keys: list[str],
    results: list[dict[str, Any]],
    meta: dict[str, Any],
) -> SampleSet:
    import pandas as pd

    from ..study import SampleSet

    runs = pd.DataFrame({"run_id": np.arange(1, len(results) + 1)})
    case_ids = (
        design["case_id"].astype(str).to_numpy()
        if "case_id" in design
        else [f"run-{i + 1:03d}" for i in range(len(results))]
    )
    runs["case_id"] = case_ids
    for name in space.names:
        runs[name] = design[name].to_numpy(dtype=float)
    runs["f60_n"] = [r.get("f60_n", np.nan) for r in results]
    runs["theta_sat_deg"] = [r.get("theta_sat_deg", np.nan) for r in results]
    runs["saturated"] = [bool(r.get("saturated", False)) for r in results]
    runs["status"] = [r["status"] for r in results]
    runs["reason"] = [r.get("reason", "") for r in results]
    runs["input_hash"] = keys
    frames = [
        pd.DataFrame(
            {
                "run_id": run_id,
                "angle_deg": r["angle_deg"],
                "force_n": r["force_n"],
                "force_perp_n": r["force_perp_n"],
            }
        )
        for run_id, r in zip(runs["run_id"], results, strict=True)
        if r["status"] == "ok"
    ]
    curves = (
        pd.concat(frames, ignore_index=True)
        if frames
        else pd.DataFrame(columns=["run_id", "angle_deg", "force_n", "force_perp_n"])
    )
    return SampleSet(runs, curves, space, meta)
