"""Write the shipped synthetic measurement set with a hidden effect.

    .venv/bin/python scripts/make_measurements.py

``data/measurements/webbing_tests.csv`` is SYNTHETIC: ten bending tests made by
the built-in solver at varied conditions (end tension 0–40 N, warp/weft,
9–900 °/s, replicates), with Gaussian noise and one physical effect switched
on that the base model lacks. Which one, and its value, is written to
``tests/data/webbing_tests_truth.json`` — read only by the tests, never by the
product. The lab temperature column is a decoy: it varies but does not matter.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from surrogate._io import atomic_write_text  # noqa: E402
from surrogate.calibration._synthetic import synthetic_measurements  # noqa: E402

SEED = 20261121
NOISE_N = 0.05
COATING = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
HIDDEN = {"tension": {"k_e": 0.006, "k_s": 0.006}}
TESTS = [
    {"test_id": "T01", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T02", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T03", "tension_n": 10.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T04", "tension_n": 20.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T05", "tension_n": 20.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T06", "tension_n": 40.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "T07", "tension_n": 0.0, "direction": "weft", "rate_deg_s": 90.0},
    {"test_id": "T08", "tension_n": 20.0, "direction": "weft", "rate_deg_s": 90.0},
    {"test_id": "T09", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 9.0},
    {"test_id": "T10", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 900.0},
]
TEMPERATURE_C = [21.5, 23.0, 22.1, 24.8, 21.0, 23.6, 22.4, 25.1, 21.8, 24.0]


def main(root: Path = ROOT) -> None:
    """Write the data set and its truth under ``root`` (the repository by default)."""
    tests = [{**t, "temperature_c": c} for t, c in zip(TESTS, TEMPERATURE_C, strict=True)]
    table = synthetic_measurements(
        tests, coating=COATING, effects=HIDDEN, noise_n=NOISE_N, seed=SEED
    )
    out = root / "data" / "measurements" / "webbing_tests.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    (root / "tests" / "data").mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, table.to_csv(index=False, float_format="%.6g"))
    truth = {
        "note": "truth of data/measurements/webbing_tests.csv; for tests only",
        "seed": SEED,
        "noise_n": NOISE_N,
        "coating": COATING,
        "hidden_effects": HIDDEN,
        "decoy_covariates": ["temperature_c", "direction", "rate_deg_s"],
    }
    atomic_write_text(
        root / "tests" / "data" / "webbing_tests_truth.json", json.dumps(truth, indent=2) + "\n"
    )
    print(f"wrote {out}: {table.test_id.nunique()} tests, {len(table)} rows")


if __name__ == "__main__":
    main()
