"""How smooth CalculiX's curves are in the coating: the issue-16 calibrations judge local
optima by finite differences of ~1/64 of ±5 % of a range, and CalculiX runs with automatic
increments, whose path changes with the parameters.

At a coating and its neighbours — Scoat and Tcoat each scaled by (1 + ε), ε from 1e-4 to
1e-2 — both solvers run at two bending lengths (10 and 15 mm); printed per solver and ε:
the RMS over angles of the curve's change from the base curve [N] and its largest change
over the base force [%], and the change over ε (a smooth response changes in proportion
to ε: that ratio stays put as ε shrinks; a scattered one does not). The built-in solver
beside it is the smooth reference.

Run: .venv/bin/python benchmarks/calculix_scatter.py [--coat paper|mid] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import numpy as np  # noqa: E402

import surrogate  # noqa: E402
from benchmarks._machine import machine  # noqa: E402
from benchmarks.fidelity import CALIBRATIONS, SOLVER  # noqa: E402
from surrogate import SolverError  # noqa: E402

EPSILONS = (1e-4, 1e-3, 1e-2)
LENGTHS = (10.0, 15.0)
MOVED = ("scoat_gpa", "tcoat_mm")


def _curve(task: tuple[str, dict[str, float], float]) -> np.ndarray:
    solver, coat, length = task
    settings = {"mesh": SOLVER["mesh"]} if solver == SOLVER["kind"] else None
    try:
        curve = surrogate.simulate(
            **coat,
            conditions={"bending_length_mm": length},
            solver=solver,
            solver_settings=settings,
        )
    except SolverError:  # the comparison leaves that coat out
        return np.full(91, np.nan)
    return np.interp(np.arange(91.0), curve.angle_deg, curve.force_n, right=np.nan)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coat", choices=sorted(CALIBRATIONS), default="paper")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    base = CALIBRATIONS[args.coat]
    coats = [("base", 0.0, base)] + [
        (name, eps, {**base, name: base[name] * (1 + eps)}) for name in MOVED for eps in EPSILONS
    ]
    print(f"coat {args.coat} {base}; {machine()}")
    for solver in ("builtin", SOLVER["kind"]):
        tasks = [(solver, coat, length) for _, _, coat in coats for length in LENGTHS]
        with ProcessPoolExecutor(args.jobs) as pool:
            curves = np.array(list(pool.map(_curve, tasks))).reshape(len(coats), len(LENGTHS), 91)
        for (name, eps, _), moved in zip(coats[1:], curves[1:], strict=True):
            change = moved - curves[0]
            rms = float(np.sqrt(np.nanmean(change**2)))
            largest = float(np.nanmax(np.abs(change) / np.maximum(np.abs(curves[0]), 1e-9)))
            print(
                f"{solver:9s} {name:10s} ε {eps:7.0e}  RMS change {rms:9.3g} N  largest "
                f"{100 * largest:7.3g} %  RMS/ε {rms / eps:9.3g} N"
            )


if __name__ == "__main__":
    main()
