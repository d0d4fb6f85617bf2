"""Benchmark of the built-in solver's smoothness: do its curves jump where the coat changes
by nothing?

Calibration, profiles and first-order tests assume curves that change continuously with
the parameters. This takes every truth of the coverage benchmark (``coverage_sets``: the
coat, its effects and its tests), solves each condition group at ``--points`` coats along
Scoat (±1 %, the other parameters held), finds the largest change between neighbours
beyond their median one (the angle where it lies), and halves that interval
``--bisections`` times (30: a share of 2·10⁻¹² of Scoat). A smooth curve's change shrinks
with the interval; a jump does not: what is left is the jump, printed against the set's
noise, with the contact point (arc length from the clamp) on each side of it. Then the
number of curves that jump by more than 0.5, 1 and 2 × their set's noise, by end tension.

``--element-size`` solves on the uniform mesh of that size (``element_size_mm``) instead of
the default graded one (about 0.4 mm segments over the loaded zone at 10 mm).

Run: .venv/bin/python benchmarks/smoothness.py [--count 240] [--jobs 2] [--element-size MM]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks._machine import machine  # noqa: E402
from surrogate._errors import SolverError  # noqa: E402
from surrogate.calibration._problem import CalibrationProblem, load_calibration  # noqa: E402
from surrogate.calibration._synthetic import (  # noqa: E402
    coverage_sets,
    true_parameters,
    write_calibration_study,
)
from surrogate.solvers._builtin import solve_state  # noqa: E402

SPAN = 0.01  # Scoat ±1 %


def _problem(case: dict[str, Any], element_size: float | None) -> CalibrationProblem:
    with tempfile.TemporaryDirectory() as folder:
        path = write_calibration_study(Path(folder), case, seed=case["study_seed"])
        spec, data, effects, _ = load_calibration(path, None, ())
    if element_size is not None:
        rig = dataclasses.replace(spec.rig, element_size_mm=element_size)
        spec = dataclasses.replace(spec, rig=rig)
    return CalibrationProblem(spec, data, effects)


def _curve(problem: CalibrationProblem, theta: np.ndarray, group: int, column: str = "force_n"):
    try:
        return getattr(solve_state(problem.state(theta, group)), column)
    except SolverError:
        return np.full(problem.angle_deg.size, np.nan)


def jumps(case: dict[str, Any], points: int, bisections: int, element_size: float | None):
    """The set's largest jump per condition group: (conditions, jump [N], angle, the contact
    point's arc length [mm] on either side)."""
    problem = _problem(case, element_size)
    names = problem.space.names
    truth = true_parameters(case)
    theta0 = np.array([truth[name] for name in names])
    k = names.index("scoat_gpa")

    def at(share: float) -> np.ndarray:
        theta = theta0.copy()
        theta[k] *= 1.0 + share
        return theta

    shares = np.linspace(-SPAN, SPAN, points)
    found = []
    for group, conditions in enumerate(problem.groups):
        curves = np.array([_curve(problem, at(s), group) for s in shares])
        steps = np.diff(curves, axis=0)
        off = np.abs(steps - np.median(steps, axis=0))
        if not np.isfinite(off).any():
            found.append((conditions, float("nan"), -1, (np.nan, np.nan)))
            continue
        i, angle = np.unravel_index(int(np.nanargmax(off)), off.shape)
        low, high = shares[i], shares[i + 1]
        f_low, f_high = curves[i, angle], curves[i + 1, angle]
        for _ in range(bisections):
            mid = 0.5 * (low + high)
            f_mid = _curve(problem, at(mid), group)[angle]
            if abs(f_mid - f_low) >= abs(f_high - f_mid):
                high, f_high = mid, f_mid
            else:
                low, f_low = mid, f_mid
        arcs = tuple(_curve(problem, at(s), group, "contact_arc_mm")[angle] for s in (low, high))
        found.append((conditions, float(abs(f_high - f_low)), int(angle), arcs))
    return case["name"], case["noise_n"], found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=240, help="coverage sets (default 240)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--points", type=int, default=11, help="coats along Scoat (default 11)")
    parser.add_argument("--bisections", type=int, default=30)
    parser.add_argument("--element-size", type=float, help="uniform mesh [mm] (default: graded)")
    args = parser.parse_args()
    sets = coverage_sets(args.count)
    mesh = f"uniform {args.element_size} mm" if args.element_size else "the default graded mesh"
    print(f"{len(sets)} coverage truths, {mesh}, {args.jobs} processes; {machine()}", flush=True)
    started = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [
            pool.submit(jumps, case, args.points, args.bisections, args.element_size)
            for case in sets
        ]
        for future in futures:
            name, noise, found = future.result()
            for conditions, jump, angle, _ in found:
                rows.append((name, noise, conditions.get("tension_n", 0.0), jump, angle))
            worst = max(found, key=lambda f: np.nan_to_num(f[1], nan=-1.0))
            if worst[1] > 0.5 * noise:
                print(
                    f"{name}: {worst[1]:.4f} N = {worst[1] / noise:.2f} × noise at {worst[2]}° "
                    f"({', '.join(f'{k} {v:g}' for k, v in worst[0].items())}), contact at "
                    f"{worst[3][0]:.3f} | {worst[3][1]:.3f} mm",
                    flush=True,
                )
    print()
    for tension in sorted({r[2] for r in rows}):
        ratios = [r[3] / r[1] for r in rows if r[2] == tension and np.isfinite(r[3])]
        print(
            f"end tension {tension:g} N: {len(ratios)} curves; a jump over 0.5 × noise in "
            f"{sum(x > 0.5 for x in ratios)}, over 1 × in {sum(x > 1 for x in ratios)}, over "
            f"2 × in {sum(x > 2 for x in ratios)}; median {statistics.median(ratios):.2g} × noise"
        )
    per_set: dict[str, float] = {}
    for name, noise, _, jump, _ in rows:
        if np.isfinite(jump):
            per_set[name] = max(per_set.get(name, 0.0), jump / noise)
    print(
        f"sets with a jump over 1 × their noise: {sum(x > 1 for x in per_set.values())} of "
        f"{len(per_set)}; wall time {time.perf_counter() - started:.0f} s"
    )


if __name__ == "__main__":
    main()
