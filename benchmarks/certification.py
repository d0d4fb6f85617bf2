"""Benchmark of the expensive solver's certificate of a multi-fidelity calibration (issue 16).

Where the corrected built-in model's first-order test held at a point the expensive
solver verified, ``calibrate`` runs the expensive solver's own test there when the budget
holds it — differenced along the fit coordinates the curves depend on (k × G runs; the
corrected model's slopes along those they hardly depend on, where the misfit is within
the noise), else along all (p × G); a diagnosis's calibrations do not (``certify=False``).
This runs both side by side on the test-only "expensive" solver of ``tests/fidelity.py``
(the built-in solver with a known smooth distortion: ``plain`` the default one, whose
curves hardly depend on Tcoat at fixed D and Mp; ``smooth`` with ``thick``, whose curves
do; ``rough`` also a 1 % ripple in D that a finite-difference Jacobian sees): three
coatings (``tests/test_fidelity.py``'s ``TRUTHS``) × noise seeds × the three distortions,
two bending lengths, noise 0.05 N, budget 30. Per calibration: status, whose first-order
test held (``multi_fidelity.optimum_tested_by``, and ``tested_along`` where only the
determined coordinates were the expensive solver's), expensive runs, RMSE over the
truth's own RMSE on the same data, the errors of D and Mp and whether the stated 95 %
intervals hold the truth's; where the test was the determined coordinates', whether the
expensive solver's whole test (its runs not counted) holds at the same point too.
Summary per distortion and mode: converged, intervals holding both D and Mp among the
converged, runs (median, max), the worst RMSE ratio of a converged one, how many were
certified along the determined coordinates and how many of those the whole test refutes.

Run: .venv/bin/python benchmarks/certification.py [--seeds 0,1,2,3] [--jobs 2] [--out F]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks._machine import machine  # noqa: E402
from benchmarks._truth import inside, mark  # noqa: E402
from surrogate.calibration._calibrate import run_calibration  # noqa: E402
from surrogate.calibration._local import ResidualModel, optimum_test  # noqa: E402
from surrogate.calibration._problem import coat_section  # noqa: E402
from surrogate.solvers._base import _REGISTRY  # noqa: E402
from tests.fidelity import DistortedSolver  # noqa: E402
from tests.test_fidelity import BENDING, TRUTHS, _calibration_study, _truth_rmse  # noqa: E402

DISTORTIONS = {
    "plain": "",  # the default distortion: the curves hardly depend on Tcoat at fixed D and Mp
    "smooth": "thick = 0.15",
    "rough": "thick = 0.15\nrough = 0.01",
}


def calibrate_set(task: tuple[str, int, int]) -> list[dict[str, Any]]:
    """One data set calibrated without, then with the certificate (the second reuses the
    first's runs from the study's cache: its runs are counted all the same)."""
    distortion, coating, seed = task
    _REGISTRY[DistortedSolver.name] = DistortedSolver
    settings = DISTORTIONS[distortion]
    truth = TRUTHS[coating]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        path = _calibration_study(Path(folder), BENDING, truth, seed=seed, settings=settings)
        floor = _truth_rmse(path, truth, dict(tomllib.loads(settings)))
        for certify in (False, True):
            result, loop = run_calibration(path, progress=False, record=False, certify=certify)
            (d, mp), (d0, mp0) = coat_section(result.params, 1.2), coat_section(truth, 1.2)
            combinations = (result.determination or {}).get("combinations", {})
            covered = [
                inside(d0, combinations.get("bending_stiffness_nmm")),
                inside(mp0, combinations.get("plastic_moment_n")),
            ]
            rows.append(
                {
                    "distortion": distortion,
                    "coating": coating,
                    "seed": seed,
                    "certify": certify,
                    "status": result.status,
                    "misfit": result.misfit,
                    "tested_by": result.multi_fidelity["optimum_tested_by"],
                    "runs": result.solver_calls,
                    "rmse_over_truth": result.rmse_n / floor,
                    "d_error": d / d0 - 1.0,
                    "mp_error": mp / mp0 - 1.0,
                    "covered": covered,
                    "tested_along": result.multi_fidelity.get("tested_along"),
                    "whole_test_holds": _whole_test_holds(loop),
                }
            )
    return rows


def _whole_test_holds(loop: Any) -> bool | None:
    """Where the certificate differenced the expensive solver along the determined
    coordinates only (``tested_along``): whether its whole first-order test (p·G runs,
    not counted in the calibration's) holds at the same point too; None elsewhere."""
    if getattr(loop, "partly", None) is None:
        return None
    best = loop.best()
    return optimum_test(ResidualModel(loop.problem, loop.runs), best.theta).converged


def summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for distortion in DISTORTIONS:
        for certify in (False, True):
            some = [r for r in rows if r["distortion"] == distortion and r["certify"] == certify]
            done = [r for r in some if r["status"] == "converged"]
            runs = [r["runs"] for r in done]
            out.append(
                {
                    "distortion": distortion,
                    "certify": certify,
                    "converged": f"{len(done)}/{len(some)}",
                    "both_covered": f"{sum(all(r['covered']) for r in done)}/{len(done)}",
                    "median_runs": statistics.median(runs) if runs else None,
                    "max_runs": max(runs, default=None),
                    "worst_rmse_over_truth": max(
                        (r["rmse_over_truth"] for r in done), default=None
                    ),
                    "tested_along_determined": sum(r["tested_along"] is not None for r in done),
                    "whole_test_disagrees": sum(r["whole_test_holds"] is False for r in done),
                }
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--seeds", default="0,1,2,3", help="noise seeds (default 0,1,2,3)")
    parser.add_argument("--out", type=Path, help="write the rows and the summary as JSON")
    args = parser.parse_args()
    tasks = [
        (distortion, coating, int(seed))
        for distortion in DISTORTIONS
        for coating in range(len(TRUTHS))
        for seed in args.seeds.split(",")
    ]
    print(f"{len(tasks)} data sets × 2 calibrations, {args.jobs} processes; {machine()}")
    print(
        f"{'distortion':<11}{'coat':>5}{'seed':>5}{'certify':>8}{'runs':>6}{'RMSE/truth':>11}"
        f"{'D err %':>9}{'Mp err %':>9}{'D,Mp in 95%':>13}  status / misfit / tested by",
        flush=True,
    )
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for found in pool.map(calibrate_set, tasks):
            for r in found:
                rows.append(r)
                cover = ",".join(map(mark, r["covered"]))
                print(
                    f"{r['distortion']:<11}{r['coating']:>5}{r['seed']:>5}{r['certify']!s:>8}"
                    f"{r['runs']:>6}{r['rmse_over_truth']:>11.3f}{100 * r['d_error']:>9.2f}"
                    f"{100 * r['mp_error']:>9.2f}{cover:>13}  {r['status']} / {r['misfit']} / "
                    f"{r['tested_by']}"
                    + (
                        f" along {r['tested_along']['own']} (whole test holds: "
                        f"{r['whole_test_holds']})"
                        if r["tested_along"]
                        else ""
                    ),
                    flush=True,
                )
    result = summary(rows)
    for line in result:
        print(json.dumps(line))
    if args.out:
        args.out.write_text(json.dumps({"rows": rows, "summary": result}, indent=1))


if __name__ == "__main__":
    main()
