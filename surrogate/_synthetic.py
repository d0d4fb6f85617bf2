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

__all__ = ["synthetic_measurements"]


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
