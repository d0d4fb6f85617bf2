"""How far CalculiX's curves lie from the built-in rod's, and how much of that is the
coat's ``*PLASTIC`` table: the multi-fidelity correction (README, "Multi-fidelity") must
learn this gap, and a gap that grows with the coating and the conditions is a hard one.

At the truths of ``benchmarks/fidelity.py`` — its calibrations at 10 and 15 mm, its
diagnoses with their hidden effect at their tests' conditions, and the hardening
coating without it — the built-in solver and CalculiX (coarse mesh, no result cache)
run the same inputs. CalculiX runs once per ``--tables`` variant: each sets the growth
of the bottom (compressed) and top (stretched) coat's true stress with plastic strain
(``surrogate.solvers._calculix.TABLE_GROWTH``, :func:`plastic_table`):

- ``deck`` (1, 1): the shipped deck, Scoat a nominal yield stress in tension;
- ``flat`` (0, 0): a flat true stress (deck 9's);
- ``flat-bottom`` (0, 1): the deck's table on the stretched coat only;
- ``rod`` (−1, 1): the rod's law, a nominal Scoat in tension and in compression.

Only ``deck`` is what the product runs; the others are what-ifs for this comparison.
Printed per case and variant: how the run finished (its increments), the RMS of
CalculiX − built-in over the curve as a part of the built-in curve's RMS, and the
differences at 60° and 90° [%].

Run: .venv/bin/python benchmarks/calculix_gap.py [--tables deck,flat,flat-bottom,rod]
     [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import numpy as np  # noqa: E402

from benchmarks._machine import machine  # noqa: E402
from benchmarks.fidelity import CALIBRATIONS, DIAGNOSES, SOLVER, TWO_LENGTHS  # noqa: E402
from surrogate import Rig  # noqa: E402
from surrogate.solvers import _calculix, get_solver  # noqa: E402
from surrogate.solvers._batch import solver_inputs  # noqa: E402

TABLES = {  # name: growth of the (bottom, top) coat's true stress
    "deck": (1.0, 1.0),
    "flat": (0.0, 0.0),
    "flat-bottom": (0.0, 1.0),
    "rod": (-1.0, 1.0),
}
KEPT = ("bending_length_mm", "tension_n")  # the conditions that move these curves


def cases() -> dict[str, tuple[dict[str, float], dict[str, Any] | None, dict[str, Any]]]:
    """Name → (coating, effects, conditions) at the fidelity benchmark's truths."""
    found: dict[str, tuple[dict[str, float], dict[str, Any] | None, dict[str, Any]]] = {}
    for name, coating in CALIBRATIONS.items():
        for test in TWO_LENGTHS:
            found[f"{name} {test['bending_length_mm']:g} mm"] = (
                coating,
                None,
                {"bending_length_mm": test["bending_length_mm"]},
            )
    for name, (coating, hidden, tests) in DIAGNOSES.items():
        for test in tests:
            conditions = {key: test[key] for key in KEPT if key in test}
            label = ", ".join(
                f"{value:g} {'mm' if key == 'bending_length_mm' else 'N'}"
                for key, value in conditions.items()
            )
            found[f"{name} {label}"] = (coating, hidden, conditions)
            if name == "hardening":
                found[f"hardening's coat, no effect, {label}"] = (coating, None, conditions)
    return found


def _run(task: tuple[str, str]) -> dict[str, Any]:
    case, table = task
    coating, effects, conditions = cases()[case]
    kind, settings = "builtin", None
    if table != "builtin":
        kind, settings = SOLVER["kind"], {"mesh": SOLVER["mesh"]}
        bottom, top = TABLES[table]
        _calculix.TABLE_GROWTH = {"BOTCOAT": bottom, "TOPCOAT": top}  # this process only
    inputs = solver_inputs(
        coating,
        Rig(),
        solver=kind,
        effects=effects,
        conditions=conditions,
        solver_settings=settings,
    )
    start = time.perf_counter()
    result = get_solver(kind).solve(inputs)
    force = result.get("force_n")
    return {
        "case": case,
        "table": table,
        "seconds": time.perf_counter() - start,
        "force": None if force is None else np.asarray(force, dtype=float),
        "increments": result.get("increments", ""),
        "retried_after": result.get("retried_after", ""),
        "reason": result.get("reason", ""),
    }


def _gap(run: dict[str, Any], rod: np.ndarray) -> str:
    force = run["force"]
    if force is None:
        return f"failed: {run['reason']}"
    n = min(force.size, rod.size)
    rms = np.sqrt(np.mean((force[:n] - rod[:n]) ** 2)) / np.sqrt(np.mean(rod[:n] ** 2))
    at = {angle: 100 * (force[angle] / rod[angle] - 1) for angle in (60, 90)}
    how = run["increments"] if not run["retried_after"] else f"retried: {run['increments']}"
    return f"RMS gap {100 * rms:5.1f} %  F60 {at[60]:+6.1f} %  F90 {at[90]:+6.1f} %  {how}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", default=",".join(TABLES))
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    tables = [name.strip() for name in args.tables.split(",") if name.strip()]
    unknown = [name for name in tables if name not in TABLES]
    if unknown or not tables:
        parser.error(f"--tables takes names from {', '.join(TABLES)}, got {args.tables!r}")
    print(f"{machine()}; CalculiX deck {_calculix.DECK_VERSION}, {SOLVER['mesh']} mesh")
    tasks = [(case, table) for case in cases() for table in ["builtin", *tables]]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        runs = {(r["case"], r["table"]): r for r in pool.map(_run, tasks)}
    for case in cases():
        rod = runs[(case, "builtin")]["force"]
        print(f"{case}: built-in F60 {rod[60]:.3f} N, F90 {rod[90]:.3f} N")
        for table in tables:
            run = runs[(case, table)]
            print(f"  {table:12s} {_gap(run, rod)}  ({run['seconds']:.0f} s)")
    print(f"wall time {time.perf_counter() - start:.0f} s, {args.jobs} at once")


if __name__ == "__main__":
    main()
