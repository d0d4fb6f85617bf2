"""Synthetic measured curves: the built-in solver plus noise, for tests and demos.

Used by ``scripts/make_measurements.py`` (the shipped data set with a hidden
effect), by the tests and by the diagnosis benchmark. Never used to read data:
the product only ever sees the CSV files this writes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ._conditions import CONDITIONS
from ._rig import Rig
from ._simulate import simulate

__all__ = ["HIDDEN_EFFECT_TESTS", "hidden_effect_tests", "synthetic_measurements"]


def synthetic_measurements(
    tests: Sequence[Mapping[str, Any]],
    *,
    coating: Mapping[str, float],
    effects: Mapping[str, Mapping[str, float]] | None = None,
    noise_n: float,
    seed: int,
    rig: Rig | None = None,
    angles_deg: np.ndarray | None = None,
) -> pd.DataFrame:
    """Measured curves in the long format of design.md §5.

    Parameters
    ----------
    tests : sequence of mappings
        One per test: ``test_id``, any conditions (``tension_n``, ``direction``,
        ``rate_deg_s``, …) and any covariate columns (e.g. ``temperature_c``).
    coating : mapping
        ``ecoat_gpa``, ``scoat_gpa``, ``tcoat_mm`` of the truth.
    effects : mapping, optional
        Effects switched on in the truth, with their parameters.
    noise_n : float
        Standard deviation of the Gaussian measurement noise [N]; forces are
        clipped at 0 (a load cell reads no pull).
    seed : int
        Seed of the noise.
    """
    rng = np.random.default_rng(seed)
    angles = np.arange(0.0, 91.0) if angles_deg is None else np.asarray(angles_deg, float)
    frames = []
    for test in tests:
        conditions = {k: v for k, v in test.items() if k in CONDITIONS}
        curve = simulate(
            coating["ecoat_gpa"],
            coating["scoat_gpa"],
            coating["tcoat_mm"],
            rig=rig,
            effects=effects,
            conditions=conditions,
        )
        force = np.interp(angles, curve.angle_deg, curve.force_n)
        noisy = np.maximum(force + noise_n * rng.standard_normal(angles.size), 0.0)
        frame = pd.DataFrame({"test_id": test["test_id"], "angle_deg": angles, "force_n": noisy})
        for key, value in test.items():
            if key != "test_id":
                frame[key] = value
        frames.append(frame)
    table = pd.concat(frames, ignore_index=True)
    table["force_n"] = table["force_n"].round(4)
    return table


# The tests of a hidden-effect data set (tests and benchmarks/diagnosis.py): replicates
# at the reference conditions, one test off them in each condition a built-in effect
# reads (tension, weft direction, a fast and a slow rate), and two decoy covariates
# that vary from test to test but never enter the physics.
HIDDEN_EFFECT_TESTS = (
    {"test_id": "ref-1", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "ref-2", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "tension", "tension_n": 20.0, "direction": "warp", "rate_deg_s": 90.0},
    {"test_id": "weft", "tension_n": 0.0, "direction": "weft", "rate_deg_s": 90.0},
    {"test_id": "fast", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 900.0},
    {"test_id": "slow", "tension_n": 0.0, "direction": "warp", "rate_deg_s": 9.0},
)


def hidden_effect_tests(seed: int, tests: Sequence[Mapping[str, Any]] = HIDDEN_EFFECT_TESTS):
    """``tests`` with decoy covariates ``temperature_c`` and ``humidity_pct`` drawn per test."""
    rng = np.random.default_rng(seed)
    return [
        {
            **test,
            "temperature_c": round(float(rng.uniform(19.0, 27.0)), 1),
            "humidity_pct": round(float(rng.uniform(30.0, 60.0)), 0),
        }
        for test in tests
    ]
