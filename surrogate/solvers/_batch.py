"""Batch evaluation of a design with the full solver: workers, cache, progress."""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

from .._errors import InputDataError
from ..physics import SOLVER_VERSION
from ..study._rig import Rig
from ..study._samples import SampleSet
from ..study._space import COATING_PARAMETERS, ParameterSpace
from ._cache import ResultCache, input_hash

__all__ = ["evaluate_design", "solve_inputs", "solver_inputs"]

SOLVERS = ("builtin", "calculix", "lsdyna")


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
    solver, see :mod:`surrogate.solvers`) enter it too, as
    ``inputs["solver_settings"]`` — only when there are any, so builtin hashes
    stay what they were.
    """
    if solver not in SOLVERS:
        raise InputDataError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    missing = [name for name in COATING_PARAMETERS if name not in point]
    if missing:
        raise InputDataError(
            f"a solver run needs {', '.join(COATING_PARAMETERS)}; missing {', '.join(missing)}"
        )
    inputs: dict[str, Any] = {
        "solver": solver,
        "solver_version": _solver_version(solver),
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


def _solver_version(solver: str) -> str:
    from . import get_solver

    return get_solver(solver).version or SOLVER_VERSION


def solve_inputs(inputs: dict[str, Any]) -> dict[str, Any]:
    """Run the solver named by ``inputs["solver"]`` (:func:`surrogate.solvers.get_solver`)
    on :func:`solver_inputs`; a failure is a result, not an exception."""
    from . import get_solver

    return get_solver(inputs.get("solver", "builtin")).solve(inputs)


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
    if not isinstance(jobs, int) or jobs < 1:
        raise InputDataError(f"jobs must be a whole number ≥ 1, got {jobs!r}")
    cache = ResultCache(cache_dir) if cache_dir is not None else None
    points = design[list(space.names)].to_dict("records")
    inputs = [
        solver_inputs(point, rig, solver=solver, solver_settings=solver_settings)
        for point in points
    ]
    keys = [input_hash(item) for item in inputs]
    results: dict[int, dict[str, Any]] = {}
    for index, key in enumerate(keys):
        hit = cache.get(key) if cache is not None else None
        if hit is not None:
            results[index] = hit
    todo = [i for i in range(len(inputs)) if i not in results]
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
        for index, result in _run(todo, inputs, solve, jobs):
            results[index] = result
            if cache is not None:
                cache.put(keys[index], inputs[index], result)
            bar.update(1)
            bar.set_postfix(failed=sum(r["status"] != "ok" for r in results.values()))
    finally:
        bar.close()
    provenance = {
        "solver": solver,
        "solver_version": _solver_version(solver),
        "rig": rig.to_dict(),
        "solver_calls": len(todo),
        **(meta or {}),
    }
    return _sample_set(design, space, keys, [results[i] for i in range(len(inputs))], provenance)


def _run(
    todo: list[int],
    inputs: list[dict[str, Any]],
    solve: Callable[[dict[str, Any]], dict[str, Any]],
    jobs: int,
):
    if jobs == 1 or len(todo) <= 1:
        for index in todo:
            yield index, solve(inputs[index])
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        pending: dict[Future[dict[str, Any]], int] = {}
        queue = list(todo)
        try:
            while queue or pending:
                while queue and len(pending) < 2 * jobs:
                    index = queue.pop(0)
                    pending[pool.submit(solve, inputs[index])] = index
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield pending.pop(future), future.result()
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _sample_set(
    design: pd.DataFrame,
    space: ParameterSpace,
    keys: list[str],
    results: list[dict[str, Any]],
    meta: dict[str, Any],
) -> SampleSet:
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
