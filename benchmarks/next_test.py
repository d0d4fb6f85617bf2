"""Benchmark of ``surrogate next-test`` (issue 63): does the recommended test settle what the
data leave open, better than more of the reference test and than a random test?

Truths whose data leave something open: coats whose curves at 10 mm reach no plateau
before 90° (Mp bounded from below only) and coats whose Tcoat the curves leave free; four
tests at 0, 0, 20, 20 N end tension, noise 0.05 N; ``[design]`` bending length 5–20 mm,
tension 0–60 N, two replicates. Per truth: calibrate, ``next-test`` (its default goal), then
— each on a copy of the data — add the recommended test measured at the truth (the
built-in solver plus noise), the reference test again, and ``--random`` random tests of
``[design]``, and calibrate again. Reported: whether the goal's interval holds the truth
after the recommended test; its width now, predicted and realised, against the
reference's and the random tests' (median); the realised over predicted width; and every
open side next-test says no test inside ``[design]`` closes, against the recalibrations
with each added test (the recommended, the reference, the random ones). And one
case whose effect's condition never varies (tension-free data of a coat that stiffens
with tension): the effect is listed untestable, and the diagnosis names it after the test
next-test proposes.

Targets (design.md §6): the goal's width shrinks ≥ 2× more than with the reference test
and than the random tests' median in ≥ 80 % of cases, the interval holds the truth, the
realised width within 1.5× of the predicted.

Run: .venv/bin/python benchmarks/next_test.py [--jobs 2] [--random 3] [--out next_test.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import surrogate  # noqa: E402
from benchmarks._machine import machine  # noqa: E402
from surrogate.calibration._loop import profiled_quantities  # noqa: E402
from surrogate.calibration._problem import CalibrationProblem, coat_section  # noqa: E402
from surrogate.calibration._synthetic import (  # noqa: E402
    BASE_TESTS,
    _set,
    synthetic_measurements,
    write_calibration_study,
)
from surrogate.study._measurements import load_measurements  # noqa: E402
from surrogate.study._spec import load_study  # noqa: E402

DESIGN = """
[design]
bending_length_mm = { low = 5.0, high = 17.5 }
tension_n = { low = 0.0, high = 60.0 }
replicates = 2
"""
TRUTHS = (  # no plateau at 10 mm, or Tcoat free: coats over the paper's ranges
    {"ecoat_gpa": 0.7, "scoat_gpa": 0.3, "tcoat_mm": 0.015},
    {"ecoat_gpa": 0.6, "scoat_gpa": 0.35, "tcoat_mm": 0.02},
    {"ecoat_gpa": 1.0, "scoat_gpa": 0.4, "tcoat_mm": 0.012},
    {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
    {"ecoat_gpa": 3.5, "scoat_gpa": 0.2, "tcoat_mm": 0.012},
    {"ecoat_gpa": 2.0, "scoat_gpa": 0.1, "tcoat_mm": 0.05},
    {"ecoat_gpa": 0.8, "scoat_gpa": 0.1, "tcoat_mm": 0.015},
    {"ecoat_gpa": 1.5, "scoat_gpa": 0.3, "tcoat_mm": 0.03},
)
NOISE_N = 0.05
NOT_SETTLED = ("insensitive", "absorbed", "range_end")  # next-test's left_open reasons


def _width(path: Path, name: str, entry: dict[str, Any]) -> float:
    spec = load_study(path)
    problem = CalibrationProblem(spec, load_measurements(spec.measurements_file), spec.effects)
    quantity = {q.name: q for q in profiled_quantities(problem)}[name]
    low, high = quantity.range_scaled
    a = low if entry["low"] is None else quantity.scale(entry["low"])
    b = high if entry["high"] is None else quantity.scale(entry["high"])
    return b - a


def _with_test(
    folder: Path, source: Path, truth: dict, conditions: dict, tag: str, seed: int
) -> Path:
    """A copy of the study with two replicates of a test at ``conditions``, measured at the
    truth, added to its data."""
    shutil.copytree(source.parent, folder)
    path = folder / source.name
    for db in folder.glob("*.db"):
        db.unlink()
    tests = [{"test_id": f"{tag}-{k}", **conditions} for k in (1, 2)]
    added = synthetic_measurements(tests, coating=truth, noise_n=NOISE_N, seed=seed)
    table = pd.read_csv(folder / "tests.csv")
    rig = load_study(path).rig  # the measured tests' conditions where no column says
    unstated = {"bending_length_mm": rig.bending_length_mm, "tension_n": rig.tension_n}
    for column in added.columns:
        if column not in table:
            table[column] = unstated.get(column, 0.0)
    for column in table.columns:
        if column not in added:
            added[column] = conditions.get(column, unstated.get(column, 0.0))
    pd.concat([table, added], ignore_index=True).to_csv(folder / "tests.csv", index=False)
    return path


def _covered(entry: dict[str, Any], truth: float) -> bool:
    return (entry["low"] is None or entry["low"] <= truth) and (
        entry["high"] is None or truth <= entry["high"]
    )


def run_case(task: tuple[int, int]) -> dict[str, Any]:
    index, random_tests = task
    truth = TRUTHS[index]
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        case = _set(f"nt{index}", truth, {}, [], BASE_TESTS, NOISE_N, 500 + index)
        path = write_calibration_study(root / "base", case, seed=0)
        path.write_text(path.read_text() + DESIGN)
        first = surrogate.calibrate(path, progress=False)
        if first.status != "converged":
            return {"truth": truth, "skipped": f"calibration {first.status}"}
        advice = surrogate.next_test(path, plots=False, progress=False)
        goal = advice.goal
        if goal is None:
            return {
                "truth": truth,
                "skipped": "no test settles anything",
                "message": advice.message,
            }
        d, mp = coat_section(truth, 1.2)
        true_value = {"bending_stiffness_nmm": d, "plastic_moment_n": mp, **truth}[goal]
        now = _width(
            path,
            goal,
            {**first.determination["combinations"], **first.determination["intervals"]}[goal],
        )
        best = advice.recommended[0]
        rng = np.random.default_rng(index)
        tests = {
            "recommended": best["conditions"],
            "reference": advice.reference["conditions"],
            **{
                f"random-{k}": {
                    **advice.reference["conditions"],
                    "bending_length_mm": round(float(rng.uniform(5.0, 17.5)), 3),
                    "tension_n": round(float(rng.uniform(0.0, 60.0)), 3),
                }
                for k in range(random_tests)
            },
        }
        realised, closed = {}, []
        true_values = {"bending_stiffness_nmm": d, "plastic_moment_n": mp, **truth}
        for k, (tag, conditions) in enumerate(tests.items()):
            again_path = _with_test(root / tag, path, truth, conditions, tag, 900 + 10 * index + k)
            again = surrogate.calibrate(again_path, progress=False)
            if again.determination is None:
                realised[tag] = {"status": again.status}
                continue
            entries = {**again.determination["combinations"], **again.determination["intervals"]}
            closed += _closed_sides(advice.left_open, entries, true_values, tag)
            entry = entries[goal]
            realised[tag] = {
                "width": _width(again_path, goal, entry),
                "covered": _covered(entry, true_value),
                "kind": entry["kind"],
            }
    shrink = {tag: now - r["width"] for tag, r in realised.items() if "width" in r}
    randoms = [v for tag, v in shrink.items() if tag.startswith("random")]
    predicted = best["predicted"][goal]["width_after"]
    got = realised["recommended"].get("width")
    return {
        "truth": truth,
        "goal": goal,
        "conditions": best["conditions"],
        "width_now": now,
        "predicted": predicted,
        "realised": realised,
        "covered": realised["recommended"].get("covered"),
        # a shrink of nothing beats nothing: the recommended test must narrow the goal
        "beats_reference_2x": shrink.get("recommended", 0) > 0
        and shrink.get("recommended", 0) >= 2 * max(shrink.get("reference", 0), 0),
        "beats_random_2x": bool(randoms)
        and shrink.get("recommended", 0) > 0
        and shrink.get("recommended", 0) >= 2 * max(statistics.median(randoms), 0),
        "realised_over_predicted": None if got is None or predicted <= 0 else got / predicted,
        # "no test inside [design] settles X": every open side it names, against the
        # recalibrations with each added test (all inside [design])
        "left_open": [
            (u["quantity"], side, why)
            for u in advice.left_open
            for side, why in u["reasons"].items()
        ],
        "left_open_closed": closed,
        "message": advice.message,
    }


def _closed_sides(
    left_open: list[dict[str, Any]], entries: dict[str, Any], truths: dict[str, float], tag: str
) -> list[dict[str, Any]]:
    """The open sides next-test said no candidate is predicted to close that the
    recalibration with test ``tag`` closed, each with next-test's reason and whether the
    closed side holds the truth."""
    found = []
    for item in left_open:
        entry = entries[item["quantity"]]
        for side in item["sides"]:
            if entry[side] is not None:
                truth = truths[item["quantity"]]
                holds = truth >= entry[side] if side == "low" else truth <= entry[side]
                found.append(
                    {
                        "quantity": item["quantity"],
                        "side": side,
                        "reason": item["reasons"][side],
                        "test": tag,
                        "holds": holds,
                    }
                )
    return found


def untestable_case() -> dict[str, Any]:
    """Tension-free tests of a coat that stiffens with tension: untestable, then named."""
    truth = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
    hidden = {"tension": {"k_e": 0.01, "k_s": 0.006}}
    tests = [{"test_id": f"a{k}", "tension_n": 0.0} for k in range(1, 5)]
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder) / "u"
        case = _set("untestable", truth, hidden, [], tests, NOISE_N, 77)
        path = write_calibration_study(root, case, seed=0)
        path.write_text(path.read_text() + DESIGN)
        surrogate.calibrate(path, progress=False)
        advice = surrogate.next_test(path, plots=False, progress=False)
        listed = {u["effect"]: u for u in advice.untestable}
        test = listed.get("tension", {}).get("test")
        if not isinstance(test, dict):
            return {"untestable_listed": "tension" in listed, "named_after": False}
        added = synthetic_measurements(
            [{"test_id": f"t{k}", **test} for k in (1, 2)],
            coating=truth,
            effects=hidden,
            noise_n=NOISE_N,
            seed=78,
        )
        table = pd.read_csv(root / "tests.csv")
        pd.concat([table, added], ignore_index=True).to_csv(root / "tests.csv", index=False)
        diagnosis = surrogate.diagnose(path, progress=False, jobs=1)
    return {
        "untestable_listed": True,
        "test": test,
        "named_after": diagnosis.verdict.startswith("missing effect: tension"),
        "verdict": diagnosis.verdict,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--random", type=int, default=3, help="random tests per case")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    print(f"{len(TRUTHS)} cases and the untestable one; {machine()}", flush=True)
    rows, started = [], time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(run_case, (k, args.random)) for k in range(len(TRUTHS))]
        extra = pool.submit(untestable_case)
        for future in as_completed(futures):
            row = future.result()
            rows.append(row)
            print(json.dumps(row, default=str)[:400], flush=True)
        untestable = extra.result()
    done = [r for r in rows if "skipped" not in r]
    ratios = [r["realised_over_predicted"] for r in done if r["realised_over_predicted"]]
    summary = {
        "cases": len(rows),
        "ranked": len(done),
        "covered": sum(bool(r["covered"]) for r in done),
        "beats_reference_2x": sum(r["beats_reference_2x"] for r in done),
        "beats_random_2x": sum(r["beats_random_2x"] for r in done),
        "within_1_5_of_predicted": sum(1 / 1.5 <= x <= 1.5 for x in ratios),
        # "no candidate is predicted to settle it" for want of sensitivity or because the
        # other parameters absorb it (insensitive, absorbed, range_end) is refuted by a
        # closure; "only near today's fit" (near_fit) is not: there a closure is the case
        # it names
        "left_open_sides": sum(len(r["left_open"]) for r in done),
        "not_predicted_to_settle_claims": sum(
            u[2] in NOT_SETTLED for r in done for u in r["left_open"]
        ),
        "left_open_closed_by_an_added_test": [
            {"truth": "/".join(map(str, r["truth"].values())), **c}
            for r in done
            for c in r["left_open_closed"]
        ],
        "realised_over_predicted": ratios,
        "untestable": untestable,
        "wall_s": time.perf_counter() - started,
    }
    print(json.dumps(summary, indent=1, default=str))
    if args.out:
        args.out.write_text(json.dumps({"rows": rows, "summary": summary}, indent=1, default=str))


if __name__ == "__main__":
    main()
