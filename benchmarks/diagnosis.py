"""Benchmark of the diagnosis (issue 6): is the hidden effect named, and only when there is one?

Each data set is six synthetic tests (``surrogate.calibration._synthetic.HIDDEN_EFFECT_TESTS``:
two replicates at the reference conditions, one test at 20 N tension, one weft,
one fast and one slow) with two decoy covariates (``temperature_c``,
``humidity_pct``) that vary but never enter the physics. The truth is one of
three coatings; a data set hides one built-in effect at a moderate or a strong
magnitude, at noise 0.02 N or 0.05 N — or hides nothing. ``surrogate.diagnose``
sees only the CSV and the base study (every built-in effect is a candidate).

Reported, per data set and over all:
- right first: the hidden effect is first in the ranking of a systematic misfit;
  "first or tied": it is first or fits as well as the first (``tied_with``:
  ΔBIC within 10 — hardening and membrane_bending are the same family of
  moment–curvature laws, see the README);
- false alarms: data without a hidden effect diagnosed as a systematic misfit;
- RMSE before (the calibrated base model) and after adding the top effect (its
  local refit with the full solver), both over the true noise.
Targets: right first ≥ 95 %, false alarms ≤ 5 %, RMSE after ≤ 1.3 × noise.

``--limit`` adds data sets at the detection limit (realistic webbing self-weight,
1200 g/m²; a stiff clamp), reported apart and not counted in the targets.

Run: .venv/bin/python benchmarks/diagnosis.py [--jobs 2] [--only hardening,none]
     [--limit] [--out diagnosis.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

# One BLAS thread per process: several processes, each spinning a BLAS pool on
# the same cores, ran ten times slower than one process alone.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import surrogate  # noqa: E402
from surrogate.calibration._synthetic import hidden_effect_tests, synthetic_measurements  # noqa: E402

COATINGS = (
    {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
    {"ecoat_gpa": 2.0, "scoat_gpa": 0.25, "tcoat_mm": 0.03},
    {"ecoat_gpa": 0.8, "scoat_gpa": 0.1, "tcoat_mm": 0.015},
)
NOISES = (0.02, 0.05)
# (moderate, strong) parameters of each hidden effect
MAGNITUDES: dict[str, tuple[dict[str, float], dict[str, float]]] = {
    "tension": ({"k_e": 0.003, "k_s": 0.003}, {"k_e": 0.01, "k_s": 0.006}),
    "anisotropy": ({"a_e": 1.15, "a_s": 1.1}, {"a_e": 1.6, "a_s": 1.4}),
    "rate": ({"c_e": 0.03, "c_s": 0.03}, {"c_e": 0.1, "c_s": 0.06}),
    "hardening": ({"ratio": 0.02}, {"ratio": 0.1}),
    "membrane_bending": ({"d0_nmm": 0.5}, {"d0_nmm": 3.0}),
    "friction": ({"mu": 0.2}, {"mu": 0.4}),
    "gravity": ({"areal_mass_g_m2": 5000.0}, {"areal_mass_g_m2": 15000.0}),
    "clamp_slip": ({"k_nmm_rad": 100.0}, {"k_nmm_rad": 20.0}),
}
LIMIT = {
    "gravity": {"areal_mass_g_m2": 1200.0},
    "clamp_slip": {"k_nmm_rad": 500.0},
}
STUDY = """
[study]
name = "bench"
[parameters]
ecoat_gpa = { low = 0.5,  high = 4.0, log = true }
scoat_gpa = { low = 0.05, high = 0.4, log = true }
tcoat_mm  = { low = 0.01, high = 0.1, log = true }
[measurements]
file = "tests.csv"
"""


def cases(limit: bool) -> list[dict[str, Any]]:
    """Every data set of the benchmark: 8 effects × 2 magnitudes × 2 noises + 8 without."""
    out = []
    seed = 0
    for effect, levels in MAGNITUDES.items():
        for level, params in zip(("moderate", "strong"), levels, strict=True):
            for noise in NOISES:
                seed += 1
                out.append(_case(effect, level, params, noise, seed))
    for index in range(8):
        seed += 1
        out.append(_case(None, "-", {}, NOISES[index % 2], seed))
    if limit:
        for effect, params in LIMIT.items():
            for noise in NOISES:
                seed += 1
                out.append(_case(effect, "limit", params, noise, seed))
    return out


def _case(effect: str | None, level: str, params: dict, noise: float, seed: int) -> dict:
    return {
        "hidden": effect,
        "level": level,
        "params": params,
        "noise_n": noise,
        "coating": COATINGS[seed % len(COATINGS)],
        "seed": seed,
    }


def diagnose_case(case: dict[str, Any]) -> dict[str, Any]:
    """Write the data set and study to a fresh folder, diagnose it, score the answer."""
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        hidden = {case["hidden"]: case["params"]} if case["hidden"] else None
        table = synthetic_measurements(
            hidden_effect_tests(case["seed"]),
            coating=case["coating"],
            effects=hidden,
            noise_n=case["noise_n"],
            seed=case["seed"],
        )
        table.to_csv(root / "tests.csv", index=False)
        (root / "study.toml").write_text(textwrap.dedent(STUDY))
        start = time.perf_counter()
        result = surrogate.diagnose(root / "study.toml", jobs=1, progress=False)
        seconds = time.perf_counter() - start
    top = result.ranking[0] if result.ranking else None
    first = top["effect"] if result.systematic and top else None
    return {
        **case,
        "systematic": result.systematic,
        "first": first,
        "tied_with": result.tied_with,
        "named": result.verdict.startswith("missing effect:"),
        "unexplained": (result.unexplained or {}).get("covariate"),
        "before": result.rmse_n / case["noise_n"],
        "after": (top["rmse_n"] if top else result.rmse_n) / case["noise_n"],
        "verdict": result.verdict,
        "solver_calls": result.solver_calls,
        "seconds": seconds,
    }


def _score(rows: list[dict[str, Any]]) -> dict[str, Any]:
    hidden = [r for r in rows if r["hidden"] and r["level"] != "limit"]
    null = [r for r in rows if not r["hidden"]]
    right = [r for r in hidden if r["first"] == r["hidden"]]
    tied = [r for r in hidden if r["first"] == r["hidden"] or r["hidden"] in r["tied_with"]]
    after = [r["after"] for r in right]
    return {
        "hidden": len(hidden),
        "right_first": len(right),
        "first_or_tied": len(tied),
        "null": len(null),
        "false_alarms": sum(r["systematic"] for r in null),
        "after_max": max(after, default=float("nan")),
        "after_over_1_3": sum(a > 1.3 for a in after),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2, help="data sets diagnosed at once")
    parser.add_argument("--only", help="comma-separated hidden effects to run ('none': no effect)")
    parser.add_argument("--limit", action="store_true", help="add the detection-limit data sets")
    parser.add_argument("--out", type=Path, help="write every row as JSON here")
    args = parser.parse_args()
    todo = cases(args.limit)
    if args.only:
        keep = set(args.only.split(","))
        todo = [c for c in todo if (c["hidden"] or "none") in keep]
    print(f"{len(todo)} data sets, {args.jobs} at once", flush=True)
    rows = []
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(diagnose_case, case) for case in todo]
        for future in as_completed(futures):
            row = future.result()
            rows.append(row)
            mark = "ok" if row["first"] == row["hidden"] else "--"
            print(
                f"{mark} hidden={row['hidden'] or 'none':16s} {row['level']:8s} "
                f"noise={row['noise_n']:.2f}  first={row['first'] or '-':16s} "
                f"tied={','.join(row['tied_with']) or '-':16s} "
                f"RMSE/noise {row['before']:7.2f} → {row['after']:5.2f}  "
                f"{row['solver_calls']:5d} calls {row['seconds']:5.0f} s",
                flush=True,
            )
    wall = time.perf_counter() - start
    rows.sort(key=lambda r: r["seed"])
    score = _score(rows)
    print()
    print("hidden effect      level     right first   first or tied   RMSE/noise before → after")
    for effect in [*MAGNITUDES, None]:
        for level in ("moderate", "strong", "limit", "-"):
            subset = [r for r in rows if r["hidden"] == effect and r["level"] == level]
            if not subset:
                continue
            right = sum(r["first"] == r["hidden"] for r in subset)
            tied = sum(r["first"] == r["hidden"] or (r["hidden"] in r["tied_with"]) for r in subset)
            before = " ".join(f"{r['before']:.2f}" for r in subset)
            after = " ".join(f"{r['after']:.2f}" for r in subset)
            label = effect or "none"
            if effect is None:
                alarms = sum(r["systematic"] for r in subset)
                print(f"{label:18s} {level:8s}  false alarms {alarms}/{len(subset)}   {before}")
                continue
            print(
                f"{label:18s} {level:8s}  {right}/{len(subset)}           "
                f"{tied}/{len(subset)}             {before} → {after}"
            )
    print()
    if score["hidden"]:
        print(
            f"right effect first: {score['right_first']}/{score['hidden']} "
            f"({100 * score['right_first'] / score['hidden']:.0f} %, target ≥ 95 %); "
            f"first or tied: {score['first_or_tied']}/{score['hidden']} "
            f"({100 * score['first_or_tied'] / score['hidden']:.0f} %)"
        )
        print(
            f"RMSE after adding the right top effect: max {score['after_max']:.2f} × noise, "
            f"{score['after_over_1_3']} above 1.3 (target ≤ 1.3)"
        )
    if score["null"]:
        print(
            f"false alarms: {score['false_alarms']}/{score['null']} "
            f"({100 * score['false_alarms'] / score['null']:.0f} %, target ≤ 5 %)"
        )
    print(f"wall time {wall:.0f} s with {args.jobs} processes")
    if args.out:
        args.out.write_text(json.dumps({"score": score, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
