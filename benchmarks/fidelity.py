"""Benchmark of multi-fidelity (issue 16) with CalculiX as the full solver: calibration and
diagnosis on curves CalculiX made, the built-in solver as its prior.

- calibration (``--only calibration``): a coating's curves made by CalculiX (coarse mesh)
  at two bending lengths (10 and 15 mm), noise 0.05 N (stated in the study);
  ``surrogate.calibrate`` sees only the CSV. Reported: CalculiX runs and built-in runs,
  RMSE over the truth's own RMSE on the same data (the truth's curves from CalculiX),
  the errors of D and Mp and whether the truth's D and Mp lie within the 95 % intervals the
  calibration states, status and misfit, wall time. Targets (issue 16): the noise
  floor — RMSE ≤ 1.05 × the truth's, D and Mp within 5 % — in ≤ 30 CalculiX runs.
  Beside it, after the calibration, what CalculiX's own scatter leaves of that floor:
  the RMSE of the truth's neighbours 1 % thinner and thicker at the same D and Mp
  (``NEIGHBOUR``), over the truth's — a coating that close is as good as any
  calibration can place one; where a neighbour finishes with other increments than
  the truth (a retry), its curve moves by a few per cent with them, and that ratio is
  well above 1.05 (deck 8: mid 1.31 and 1.28, both lengths automatic; deck 9: paper's
  thinner neighbour 1.12, at 15 mm with 0.5625° against the truth's 1.125°).
- diagnosis (``--only diagnosis``): CalculiX-made curves with a hidden effect —
  ``hardening`` (a yielding coat, tests at 10 and 15 mm with replicates) and
  ``tension`` (tests at 0, 20 and 40 N with replicates) — and a decoy ``temperature_c``
  column; ``surrogate.diagnose`` with every built-in effect a candidate (CalculiX cannot
  model gravity, clamp_slip and membrane_bending: skipped). Reported: the effect named,
  whether CalculiX confirmed it, CalculiX runs (and what they went to: the verdict's last
  words), the RMSE after adding it over the noise, wall time. Targets (issue 66): named
  and confirmed, ≤ 20 CalculiX runs a verdict, RMSE after ≤ 1.5 × noise (issue 16's were
  ≤ 60 runs and ≤ 1 h wall on 2 cores). With ``--work`` kept from an earlier run, runs
  at the same inputs come from its result cache (counted all the same): the wall time
  is then not CalculiX's.

The machine's cores are shared among the cases run at once (``--jobs``): each case's
``calibrate``/``diagnose`` gets cores ÷ cases-at-once processes (``jobs=``), so a case
alone runs its verifications' CalculiX runs side by side.

Every figure is printed with the machine; ``--work DIR`` keeps the study folders (their
result caches let a second run reuse the CalculiX runs: a cached run still counts as a
CalculiX run of the calibration it belongs to), each with its ``progress.log``.

Run: .venv/bin/python benchmarks/fidelity.py [--only calibration,diagnosis] [--jobs 2]
     [--cases mid,paper,hardening,tension] [--seed N] [--work DIR] [--out fidelity.json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import sys
import tempfile
import textwrap
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import surrogate  # noqa: E402
from benchmarks._machine import machine  # noqa: E402
from benchmarks._truth import inside  # noqa: E402
from surrogate.calibration._problem import coat_section  # noqa: E402
from surrogate.calibration._synthetic import synthetic_measurements  # noqa: E402

SOLVER = {"kind": "calculix", "mesh": "coarse"}
NOISE_N = 0.05
DATA_SEEDS = {"calibration": 1, "diagnosis": 2}  # the data's noise seed by kind (--seed)
NEIGHBOUR = 0.01  # the truth's neighbours: Tcoat ±1 % at the same D and Mp
TWO_LENGTHS = [
    {"test_id": "l10", "bending_length_mm": 10.0},
    {"test_id": "l15", "bending_length_mm": 15.0},
]
CALIBRATIONS = {  # name: coating of the truth
    "mid": {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
    "paper": {"ecoat_gpa": 1.0, "scoat_gpa": 0.2, "tcoat_mm": 0.012},
}
DIAGNOSES = {  # name: (coating, hidden effect, tests)
    "hardening": (
        {"ecoat_gpa": 1.2, "scoat_gpa": 0.1, "tcoat_mm": 0.02},
        {"hardening": {"ratio": 0.1}},
        [
            {"test_id": "a1", "bending_length_mm": 10.0, "temperature_c": 21.0},
            {"test_id": "a2", "bending_length_mm": 10.0, "temperature_c": 24.0},
            {"test_id": "b1", "bending_length_mm": 15.0, "temperature_c": 22.5},
            {"test_id": "b2", "bending_length_mm": 15.0, "temperature_c": 21.5},
        ],
    ),
    "tension": (
        {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
        {"tension": {"k_e": 0.006, "k_s": 0.006}},
        [
            {"test_id": "a1", "tension_n": 0.0, "temperature_c": 21.0},
            {"test_id": "a2", "tension_n": 0.0, "temperature_c": 24.0},
            {"test_id": "b", "tension_n": 20.0, "temperature_c": 22.5},
            {"test_id": "c", "tension_n": 40.0, "temperature_c": 21.5},
        ],
    ),
}


def _study(folder: Path, tests, coating, hidden, *, seed: int, stated_noise: bool) -> Path:
    """CalculiX-made data (cached in ``folder``) and the study that sees only its CSV."""
    folder.mkdir(parents=True, exist_ok=True)
    data = folder / "tests.csv"
    if not data.exists():
        table = synthetic_measurements(
            tests,
            coating=coating,
            effects=hidden,
            noise_n=NOISE_N,
            seed=seed,
            solver=SOLVER["kind"],
            solver_settings={"mesh": SOLVER["mesh"]},
        )
        table.to_csv(data, index=False)
    noise = f"noise_n = {NOISE_N}" if stated_noise else ""
    path = folder / "study.toml"
    path.write_text(
        textwrap.dedent(
            f"""
            [study]
            name = "bench"
            seed = {seed}
            [solver]
            kind = "{SOLVER["kind"]}"
            mesh = "{SOLVER["mesh"]}"
            timeout_s = 1800
            [measurements]
            file = "tests.csv"
            {noise}
            [budget]
            calibration_solver_calls = 30
            surrogate_trials = 100
            """
        )
    )
    return path


@contextlib.contextmanager
def _progress_log(folder: Path) -> Iterator[None]:
    """The case's progress messages in ``folder/progress.log`` (not on the shared stderr)."""
    logger = logging.getLogger("surrogate")
    handler = logging.FileHandler(folder / "progress.log", mode="w", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        handler.close()


def same_section(coating: dict[str, float], factor: float) -> dict[str, float]:
    """The coating of ``factor`` × its Tcoat with the same D and Mp (webbing 1.2 mm)."""
    (d, mp), tcoat = coat_section(coating, 1.2), coating["tcoat_mm"] * factor
    unit_d, unit_mp = coat_section({"ecoat_gpa": 1.0, "scoat_gpa": 1.0, "tcoat_mm": tcoat}, 1.2)
    return {"ecoat_gpa": d / unit_d, "scoat_gpa": mp / unit_mp, "tcoat_mm": tcoat}


def calibration_case(task: tuple[str, Path, int, int]) -> dict[str, Any]:
    name, work, seed, jobs = task
    truth = CALIBRATIONS[name]
    path = _study(
        work / f"calibration-{name}", TWO_LENGTHS, truth, None, seed=seed, stated_noise=True
    )
    at_truth = surrogate.compare(path, params=truth, plots=False, progress=False).rmse_n
    start = time.perf_counter()
    with _progress_log(path.parent):
        result = surrogate.calibrate(path, jobs=jobs, progress=True)
    seconds = time.perf_counter() - start
    neighbours = [
        surrogate.compare(
            path, params=same_section(truth, 1.0 + sign * NEIGHBOUR), plots=False, progress=False
        )
        for sign in (-1.0, 1.0)
    ]
    (d, mp), (d0, mp0) = coat_section(result.params, 1.2), coat_section(truth, 1.2)
    mf = result.multi_fidelity or {}
    combinations = (result.determination or {}).get("combinations", {})
    covered = {  # the truth inside the 95 % interval the product states (None: not stated)
        label: inside(truth_value, combinations.get(key))
        for label, key, truth_value in (
            ("D", "bending_stiffness_nmm", d0),
            ("Mp", "plastic_moment_n", mp0),
        )
    }
    return {
        "kind": "calibration",
        "set": name,
        "calculix_runs": result.solver_calls,
        "builtin_runs": mf.get("low_fidelity_runs"),
        "rmse_over_truth": result.rmse_n / at_truth,
        "neighbours_over_truth": [n.rmse_n / at_truth for n in neighbours],
        "d_error": d / d0 - 1.0,
        "mp_error": mp / mp0 - 1.0,
        "truth_covered": covered,
        "status": result.status,
        "misfit": result.misfit,
        "correction": mf.get("correction"),
        "dropped": mf.get("dropped"),
        "seconds": seconds,
        "message": result.message,
        "retried": result.retried,
    }


def diagnosis_case(task: tuple[str, Path, int, int]) -> dict[str, Any]:
    name, work, seed, jobs = task
    coating, hidden, tests = DIAGNOSES[name]
    path = _study(work / f"diagnosis-{name}", tests, coating, hidden, seed=seed, stated_noise=False)
    start = time.perf_counter()
    with _progress_log(path.parent):
        result = surrogate.diagnose(path, jobs=jobs, progress=True)
    seconds = time.perf_counter() - start
    top = result.ranking[0] if result.ranking else None
    mf = result.multi_fidelity or {}
    return {
        "kind": "diagnosis",
        "set": name,
        "named": result.verdict.startswith(f"missing effect: {name}") or name in result.tied_with,
        "first": top["effect"] if top else None,
        "confirmed": mf.get("confirmed"),
        "skipped": [s["effect"] for s in mf.get("skipped", [])],
        "calculix_runs": result.solver_calls,
        "builtin_runs": mf.get("low_fidelity_runs"),
        "before": result.rmse_n / result.noise_n,
        "after": (top["rmse_n"] if top else result.rmse_n) / result.noise_n,
        "unsettled": top.get("unsettled") if top else None,
        "seconds": seconds,
        "verdict": result.verdict,
    }


def _job(task: tuple[str, str, Path, int, int]) -> dict[str, Any]:
    """One case; a case that fails is a row with its error (the others go on)."""
    kind, name, work, seed, jobs = task
    start = time.perf_counter()
    try:
        case = calibration_case if kind == "calibration" else diagnosis_case
        return case((name, work, seed, jobs))
    except surrogate.InputDataError as error:
        return {
            "kind": kind,
            "set": name,
            "error": str(error),
            "seconds": time.perf_counter() - start,
        }


def _print(row: dict[str, Any]) -> None:
    if "error" in row:
        print(f"{row['kind']} {row['set']:<10} failed after {row['seconds']:.0f} s: {row['error']}")
        return
    if row["kind"] == "calibration":
        print(
            f"calibration {row['set']:<10} CalculiX runs {row['calculix_runs']:>3}  built-in runs "
            f"{row['builtin_runs']:>5}  RMSE/truth {row['rmse_over_truth']:.3f}  D err "
            f"{100 * row['d_error']:+.2f} %  Mp err {100 * row['mp_error']:+.2f} %  "
            f"{row['status']} / {row['misfit']}  {row['seconds']:.0f} s",
            flush=True,
        )
        low, high = row["neighbours_over_truth"]
        print(
            f"  the truth's neighbours (Tcoat ∓{100 * NEIGHBOUR:g} %, same D and Mp): "
            f"RMSE/truth {low:.3f}, {high:.3f}",
            flush=True,
        )
        said = {True: "yes", False: "NO", None: "no interval stated"}
        print(
            "  the truth within the product's 95 % intervals: "
            + ", ".join(f"{k} {said[v]}" for k, v in row["truth_covered"].items()),
            flush=True,
        )
        for test_id, why in (row.get("retried") or {}).items():  # at the answer
            print(f"  test {test_id} at the answer finished after a retry: {why}", flush=True)
        return
    print(
        f"diagnosis hidden {row['set']:<10} first {row['first'] or '-':<16} named "
        f"{'yes' if row['named'] else 'no'}  confirmed {','.join(row['confirmed'] or []) or '-'}  "
        f"CalculiX runs {row['calculix_runs']:>3}  built-in runs {row['builtin_runs']:>5}  "
        f"RMSE/noise {row['before']:.2f} → {row['after']:.2f}  {row['seconds']:.0f} s",
        flush=True,
    )
    if row.get("unsettled"):  # the RMSE after is an upper bound
        print(f"  its calibration stopped short: {row['unsettled']}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="calibration,diagnosis")
    parser.add_argument("--jobs", type=int, default=2, help="cases at once")
    parser.add_argument("--work", type=Path, help="keep the study folders (and their caches)")
    parser.add_argument("--out", type=Path, help="write the rows as JSON")
    parser.add_argument("--cases", help="only these cases, e.g. paper,tension (default: all)")
    parser.add_argument(
        "--seed", type=int, help="the data's noise seed (default: 1 calibrations, 2 diagnoses)"
    )
    args = parser.parse_args()
    kinds = args.only.split(",")
    names = set(args.cases.split(",")) if args.cases else set(CALIBRATIONS) | set(DIAGNOSES)
    if unknown := names - set(CALIBRATIONS) - set(DIAGNOSES):
        parser.error(
            f"unknown case(s) {', '.join(sorted(unknown))}: choose from "
            f"{', '.join([*CALIBRATIONS, *DIAGNOSES])}"
        )
    work = args.work or Path(tempfile.mkdtemp(prefix="fidelity-bench-"))
    cases = [("calibration", n) for n in CALIBRATIONS] + [("diagnosis", n) for n in DIAGNOSES]
    tasks = [
        (kind, name, work, DATA_SEEDS[kind] if args.seed is None else args.seed)
        for kind, name in cases
        if kind in kinds and name in names
    ]
    if not tasks:
        parser.error(f"no case of --only {args.only} is among --cases {args.cases}")
    # the machine's cores shared among the cases at once: a case alone gets them all (its
    # verifications' CalculiX runs side by side)
    at_once = min(args.jobs, len(tasks))
    inner = max(1, (os.cpu_count() or 1) // at_once)
    tasks = [(*task, inner) for task in tasks]
    print(
        f"{len(tasks)} cases, {at_once} at once, {inner} process(es) each; {machine()}; "
        f"work folder {work}",
        flush=True,
    )
    start = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for future in as_completed([pool.submit(_job, task) for task in tasks]):
            rows.append(future.result())
            _print(rows[-1])
    print(f"wall time {time.perf_counter() - start:.0f} s, {at_once} cases at once")
    for row in rows:
        if row["kind"] == "diagnosis" and "error" not in row:
            print(f"  {row['set']}: {row['verdict']}")
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
