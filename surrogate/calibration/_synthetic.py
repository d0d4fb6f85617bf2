"""Synthetic measured curves: the built-in solver plus noise, for tests and demos.

Used by ``scripts/make_measurements.py`` (the shipped data set with a hidden
effect), by the tests and by the diagnosis benchmark. Never used to read data:
the product only ever sees the CSV files this writes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..solvers._simulate import simulate
from ..study._conditions import CONDITIONS
from ..study._rig import Rig
from ._compare import compare
from ._determination import determination_threshold

__all__ = [
    "ANISOTROPY_BASIN_TESTS",
    "HIDDEN_EFFECT_TESTS",
    "anisotropy_basin_set",
    "calibration_sets",
    "coverage_sets",
    "hidden_effect_tests",
    "synthetic_measurements",
    "true_parameters",
    "write_calibration_study",
]


def synthetic_measurements(
    tests: Sequence[Mapping[str, Any]],
    *,
    coating: Mapping[str, float],
    effects: Mapping[str, Mapping[str, float]] | None = None,
    noise_n: float,
    seed: int,
    rig: Rig | None = None,
    angles_deg: np.ndarray | None = None,
    solver: str = "builtin",
    solver_settings: Mapping[str, Any] | None = None,
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
    solver, solver_settings : optional
        The full solver that makes the curves (default: the built-in one); tests with
        the same conditions (replicates) share one run.
    """
    rng = np.random.default_rng(seed)
    angles = np.arange(0.0, 91.0) if angles_deg is None else np.asarray(angles_deg, float)
    frames = []
    curves: dict[str, Any] = {}
    for test in tests:
        conditions = {k: v for k, v in test.items() if k in CONDITIONS}
        key = repr(sorted(conditions.items()))
        if key not in curves:
            curves[key] = simulate(
                coating["ecoat_gpa"],
                coating["scoat_gpa"],
                coating["tcoat_mm"],
                rig=rig,
                effects=effects,
                conditions=conditions,
                solver=solver,
                solver_settings=solver_settings,
            )
        curve = curves[key]
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


# -- calibration data sets (tests/test_calibrate_sweep.py and benchmarks/calibration.py) ---------
# Four tests at 0 and 20 N end tension (two replicates each, so the noise is estimated),
# 91 angles; the tension sets add 40 N.
BASE_TESTS = (
    {"test_id": "a1", "tension_n": 0.0},
    {"test_id": "a2", "tension_n": 0.0},
    {"test_id": "b1", "tension_n": 20.0},
    {"test_id": "b2", "tension_n": 20.0},
)
TENSION_TESTS = (*BASE_TESTS, {"test_id": "c1", "tension_n": 40.0})
# coatings inside the paper's ranges, two of them near corners of the space
CALIBRATION_COATINGS = {
    "mid": {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02},
    "thin-soft": {"ecoat_gpa": 0.6, "scoat_gpa": 0.06, "tcoat_mm": 0.012},
    "thick-stiff": {"ecoat_gpa": 3.5, "scoat_gpa": 0.35, "tcoat_mm": 0.09},
    "early-yield": {"ecoat_gpa": 3.0, "scoat_gpa": 0.07, "tcoat_mm": 0.05},
}


# A data set whose calibration with the right effect has a second basin (tests/test_basins.py,
# benchmarks/diagnosis.py --basins): warp and weft at three rates, two replicates each, a
# weft coat that is softer and yields earlier (anisotropy a_e 0.6, a_s 0.7). With study
# seed 2 the calibration's first local optimum lies at 21 × the noise with a_s 1.37 (no
# weft test yields; a_e makes up what it can); the truth's basin fits to the noise.
ANISOTROPY_BASIN_TESTS = tuple(
    {
        "test_id": f"{direction}-{rate:g}-{k}",
        "tension_n": 0.0,
        "direction": direction,
        "rate_deg_s": rate,
    }
    for direction in ("warp", "weft")
    for rate in (9.0, 90.0, 900.0)
    for k in (1, 2)
)


def anisotropy_basin_set() -> dict[str, Any]:
    """The data set of ``ANISOTROPY_BASIN_TESTS``, as :func:`calibration_sets` gives each
    (the model: ``anisotropy``; its basin seed: study seed 2, with the 300 surrogate
    trials of the shipped studies)."""
    case = _set(
        "anisotropy-basin",
        {"ecoat_gpa": 0.859, "scoat_gpa": 0.109, "tcoat_mm": 0.0617},
        {"anisotropy": {"a_e": 0.6, "a_s": 0.7}},
        ["anisotropy"],
        ANISOTROPY_BASIN_TESTS,
        0.06,
        1,
    )
    return {**case, "surrogate_trials": 300}


# Two bending lengths (benchmarks/coverage.py): the short one reaches the plateau sooner.
TWO_LENGTH_TESTS = (
    {"test_id": "a1", "tension_n": 0.0, "bending_length_mm": 10.0},
    {"test_id": "a2", "tension_n": 0.0, "bending_length_mm": 10.0},
    {"test_id": "b1", "tension_n": 20.0, "bending_length_mm": 15.0},
    {"test_id": "b2", "tension_n": 20.0, "bending_length_mm": 15.0},
)
PAPER_RANGES = {"ecoat_gpa": (0.5, 4.0), "scoat_gpa": (0.05, 0.4), "tcoat_mm": (0.01, 0.1)}
NEAR_BOUND = 0.03  # a coverage set's truth "near a bound": this share of the log range inside


def coverage_sets(count: int = 120, *, seed: int = 0) -> list[dict[str, Any]]:
    """The data sets of ``benchmarks/coverage.py``, as :func:`calibration_sets` gives each:
    truths over the whole coating space (a Latin hypercube of the log ranges, every
    fifth with one parameter ``NEAR_BOUND`` inside a bound), one bending length (10 mm)
    or two (10 and 15 mm), every third with the ``tension`` effect in the truth and the
    model, noise 0.02–0.08 N, each set its own noise seed and a study seed of 0–3
    (``study_seed``)."""
    from scipy.stats import qmc

    unit = qmc.LatinHypercube(d=6, seed=seed).random(count)
    names = list(PAPER_RANGES)
    sets = []
    for index, u in enumerate(unit):
        share = NEAR_BOUND + (1 - 2 * NEAR_BOUND) * u[:3]
        if index % 5 == 4:  # one parameter near a bound
            k = index // 5 % 3
            share[k] = NEAR_BOUND if u[3] < 0.5 else 1 - NEAR_BOUND
        coating = {
            name: float(np.exp(np.log(low) + share[k] * np.log(high / low)))
            for k, (name, (low, high)) in enumerate(PAPER_RANGES.items())
        }
        coating = {name: round(coating[name], 5) for name in names}
        tension = index % 3 == 2
        hidden = (
            {
                "tension": {
                    "k_e": round(float(0.002 + 0.008 * u[4]), 5),
                    "k_s": round(float(0.002 + 0.008 * u[5]), 5),
                }
            }
            if tension
            else {}
        )
        tests = TWO_LENGTH_TESTS if index % 2 else BASE_TESTS
        noise = round(float(0.02 * 4.0 ** u[3]), 4)
        case = _set(
            f"cover-{index:03d}",
            coating,
            hidden,
            ["tension"] if tension else [],
            tests,
            noise,
            1000 + index,
        )
        sets.append({**case, "study_seed": index % 4})
    return sets


def calibration_sets() -> list[dict[str, Any]]:
    """The calibration benchmark's data sets, each a mapping with ``name``,
    ``coating``, ``hidden`` (effects of the truth), ``effects`` (the model's),
    ``tests``, ``noise_n`` and ``seed`` (of the noise).

    Every coating with three noise draws (``<coating>-n1`` … ``-n3``: noise 0.02 N
    for the first, 0.05 N for the others); the ``tension`` effect (two sets);
    ``tension`` + ``hardening`` (six free parameters, two sets); and two
    *misspecified* sets (the base model on data with a hidden tension effect)
    that must end ``converged`` with a systematic misfit. Every set has a noise
    seed of its own: sets sharing one would share one draw of the noise, and
    their errors (and the intervals' misses) would be one event counted many times.
    """
    tension = {"tension": {"k_e": 0.006, "k_s": 0.004}}
    both = {**tension, "hardening": {"ratio": 0.05}}
    mid = CALIBRATION_COATINGS["mid"]
    sets = [
        _set(f"{label}-n{j}", coating, {}, [], BASE_TESTS, 0.02 if j == 1 else 0.05, 10 * i + j)
        for i, (label, coating) in enumerate(CALIBRATION_COATINGS.items())
        for j in (1, 2, 3)
    ]
    models = {
        "tension": (tension, ["tension"]),
        "tension-hardening": (both, ["hardening", "tension"]),
        "misspecified": (tension, []),
    }
    sets += [
        _set(f"{label}-n{j}", mid, hidden, effects, TENSION_TESTS, 0.05, 100 + 10 * i + j)
        for i, (label, (hidden, effects)) in enumerate(models.items())
        for j in (1, 2)
    ]
    return sets


def _set(
    name: str,
    coating: Mapping[str, float],
    hidden: Mapping[str, Mapping[str, float]],
    effects: Sequence[str],
    tests: Sequence[Mapping[str, Any]],
    noise_n: float,
    seed: int,
) -> dict[str, Any]:
    return {
        "name": name,
        "coating": dict(coating),
        "hidden": hidden,
        "effects": list(effects),
        "tests": [dict(t) for t in tests],
        "noise_n": noise_n,
        "seed": seed,
    }


def true_parameters(case: Mapping[str, Any]) -> dict[str, float]:
    """A data set's truth as a calibration names it: the coating, and each hidden effect's
    parameters as ``effect.param``."""
    values = dict(case["coating"])
    for effect, params in case["hidden"].items():
        values.update({f"{effect}.{k}": v for k, v in params.items()})
    return values


def truth_ratio(case: Mapping[str, Any], path: Path, fitted: Any) -> float:
    """The truth's misfit above the fit's in units of the profiles' 95 % threshold
    (:func:`.determination_threshold` with the calibration's own degrees of freedom, as a
    verified end's ``ratio`` is judged): ``ρ`` of the truth. ``fitted``: the calibration's
    result (its ``rmse_n`` and ``determination``). At most 1 — less the tolerance an end
    is accepted within, ``ρ`` 0.8–1.25 — every profile interval must hold the truth: the
    profile at the truth's value lies no higher than the truth's own misfit. Over 1 it
    says nothing of one interval: the truth's misfit above the fit's follows χ² with as
    many degrees as the data determine parameters, over the one-parameter threshold in
    28 % of data sets for three, 43 % for four. One run per condition group of the study
    at ``path`` (``surrogate.compare``)."""
    truth = compare(path, params=true_parameters(case), plots=False, progress=False)
    dof = int(fitted.determination["dof"])
    rss = dof * fitted.rmse_n**2  # (the point count cancels: RSS per point, times dof)
    return dof * (truth.rmse_n**2 - fitted.rmse_n**2) / determination_threshold(rss, dof)


def write_calibration_study(folder: Path, case: Mapping[str, Any], *, seed: int = 0) -> Path:
    """``tests.csv`` (the case's synthetic data) and ``study.toml`` (the paper's ranges,
    the case's effects, study seed ``seed``, its ``surrogate_trials`` or 100) in
    ``folder``; returns the study path."""
    folder.mkdir(parents=True, exist_ok=True)
    synthetic_measurements(
        case["tests"],
        coating=case["coating"],
        effects=case["hidden"] or None,
        noise_n=case["noise_n"],
        seed=case["seed"],
    ).to_csv(folder / "tests.csv", index=False)
    listed = ", ".join(f'"{e}"' for e in case["effects"])
    path = folder / "study.toml"
    path.write_text(
        f'[study]\nname = "{case["name"]}"\nseed = {seed}\n'
        "[parameters]\n"
        "ecoat_gpa = { low = 0.5,  high = 4.0, log = true }\n"
        "scoat_gpa = { low = 0.05, high = 0.4, log = true }\n"
        "tcoat_mm  = { low = 0.01, high = 0.1, log = true }\n"
        '[measurements]\nfile = "tests.csv"\n'
        f"[model]\neffects = [{listed}]\n"
        "[budget]\ncalibration_solver_calls = 200\n"
        f"surrogate_trials = {case.get('surrogate_trials', 100)}\n"
    )
    return path
