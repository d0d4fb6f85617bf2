"""How repeatable and how smooth CalculiX's curves are in the coating: the issue-16
calibrations judge local optima by finite differences of ~1/64 of ±5 % of a range.
With automatic increments and ccx's random contact part (deck 5) repeats differed by up
to 5.8 % and a 0.1 % neighbour moved as much as a 1 % one; the deck now has fixed
increments and no random part (README, "CalculiX").

At a coating, both solvers run the same inputs ``--repeats`` times (no result cache) and
at neighbours — Scoat and Tcoat each scaled by (1 + ε) — at two bending lengths (10 and
15 mm). Printed per solver: for each repeat, the RMS over angles of its difference from
the first run [N] and the largest difference over the force [%] (a deterministic solver:
0); for each neighbour, the same against the base run and that change over ε (a smooth
response changes in proportion to ε: the ratio stays put as ε shrinks). For CalculiX,
beside each, which attempt each length's run finished with (the result's
``increments``): a neighbour that finished on another attempt than the base moves by
the attempts' difference, not by ε's. The built-in
solver beside it is the smooth, repeatable reference. ``--coat probe`` is a point a
CalculiX calibration of the *paper* curves verified (Ecoat at its bound, a yielding coat).

Run: .venv/bin/python benchmarks/calculix_scatter.py [--coat probe|paper|mid] [--jobs 2]
     [--repeats 3]
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

from benchmarks._machine import machine  # noqa: E402
from benchmarks.fidelity import CALIBRATIONS, SOLVER  # noqa: E402
from surrogate import Rig, SolverError  # noqa: E402
from surrogate.solvers._simulate import _curve as _as_curve  # noqa: E402
from surrogate.solvers._simulate import solve_checked  # noqa: E402

EPSILONS = (1e-3, 1e-2)
COATS = {  # probe: a point CalculiX ran in a calibration of the paper curves (2026-11-25)
    **CALIBRATIONS,
    "probe": {"ecoat_gpa": 0.5, "scoat_gpa": 0.08182017194065078, "tcoat_mm": 0.02496312683512092},
}
LENGTHS = (10.0, 15.0)
MOVED = ("scoat_gpa", "tcoat_mm")


def _curve(task: tuple[str, dict[str, float], float]) -> tuple[np.ndarray, str]:
    """The run's force at whole degrees (NaN where it failed) and which attempt's it is
    (CalculiX's ``increments``: the deck's own or a retry's; "-" for the built-in)."""
    solver, coat, length = task
    settings = {"mesh": SOLVER["mesh"]} if solver == SOLVER["kind"] else {}
    try:  # simulate()'s own run, keeping the result's record of its attempt
        result, rig = solve_checked(
            coat, Rig(), solver, None, {"bending_length_mm": length}, settings
        )
        curve = _as_curve(result, coat, rig)
    except SolverError as error:  # the comparison leaves that coat out
        return np.full(91, np.nan), f"failed: {error}"
    attempt = str(result.get("increments") or "-")
    return np.interp(np.arange(91.0), curve.angle_deg, curve.force_n, right=np.nan), attempt


def _changes(moved: np.ndarray, base: np.ndarray) -> tuple[float, float]:
    """RMS of ``moved - base`` over every angle and length [N], and its largest part of
    the base force [%]."""
    change = moved - base
    rms = float(np.sqrt(np.nanmean(change**2)))
    return rms, 100 * float(np.nanmax(np.abs(change) / np.maximum(np.abs(base), 1e-9)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coat", choices=sorted(COATS), default="probe")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1 (the base run), got {args.repeats}")
    base = COATS[args.coat]
    coats = [("repeat", 0.0, base)] * args.repeats + [
        (name, eps, {**base, name: base[name] * (1 + eps)}) for name in MOVED for eps in EPSILONS
    ]
    print(f"coat {args.coat} {base}; {machine()}")
    for solver in ("builtin", SOLVER["kind"]):
        tasks = [(solver, coat, length) for _, _, coat in coats for length in LENGTHS]
        with ProcessPoolExecutor(args.jobs) as pool:
            runs = list(pool.map(_curve, tasks))
        curves = np.array([curve for curve, _ in runs]).reshape(len(coats), len(LENGTHS), 91)
        attempts = np.array([attempt for _, attempt in runs]).reshape(len(coats), len(LENGTHS))
        if solver != "builtin":
            print(f"{solver:9s} {'base':18s} attempts: {_attempts(attempts[0])}")
        for index, ((name, eps, _), moved) in enumerate(zip(coats, curves, strict=True)):
            if index == 0:
                continue
            rms, largest = _changes(moved, curves[0])
            what = f"repeat {index + 1}" if name == "repeat" else f"{name} ε {eps:.0e}"
            per_eps = f"  RMS/ε {rms / eps:9.3g} N" if eps else ""
            other = "" if solver == "builtin" else f"  attempts: {_attempts(attempts[index])}"
            print(
                f"{solver:9s} {what:18s} RMS change {rms:9.3g} N  largest {largest:7.3g} %"
                f"{per_eps}{other}"
            )


def _attempts(per_length: np.ndarray) -> str:
    """Which attempt each bending length's run finished with."""
    return "; ".join(f"{length:g} mm {a}" for length, a in zip(LENGTHS, per_length, strict=True))


if __name__ == "__main__":
    main()
