"""The local phase (surrogate.calibration._local): its first-order test from a point near
a local optimum, as the multi-fidelity loop hands over to the expensive solver."""

from __future__ import annotations

import re

import numpy as np
import pytest

from surrogate.calibration import _local
from surrogate.calibration._local import ResidualModel, local_fit
from surrogate.calibration._loop import SolverRuns
from surrogate.calibration._problem import CalibrationProblem, load_calibration
from surrogate.calibration._synthetic import synthetic_measurements
from tests.studies import write_study

TRUTH = {"ecoat_gpa": 1.2, "scoat_gpa": 0.15, "tcoat_mm": 0.02}
TESTS = [
    {"test_id": "l10", "bending_length_mm": 10.0},
    {"test_id": "l15", "bending_length_mm": 15.0},
]


def _problem(folder, seed: int) -> CalibrationProblem:
    table = synthetic_measurements(TESTS, coating=TRUTH, noise_n=0.05, seed=seed)
    path = write_study(
        folder,
        table,
        """
        [study]
        name = "local"
        [measurements]
        file = "tests.csv"
        noise_n = 0.05
        """,
    )
    spec, data, effects, _ = load_calibration(path, None, ())
    return CalibrationProblem(spec, data, effects)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("offset", [0.0, 0.01, -0.02])
def test_a_fit_started_near_its_optimum_is_tested_first_without_least_squares(
    tmp_path, monkeypatch, seed, offset
):
    """``near``: each round is the first-order test alone (a fresh Jacobian and a verified
    Gauss–Newton step); from the truth's noisy data, started at the truth or 1–2 % of
    Ecoat off it, it reaches a point where the test holds in at most three rounds, no
    worse than the usual fit (``least_squares``, then the test) from the same start by
    more than the test's resolution (``ROUGH_CHI2`` units of χ²: along the valley of
    equally good coatings the usual fit may move farther for 0.1 %)."""
    problem = _problem(tmp_path, seed)
    start = np.array([TRUTH["ecoat_gpa"] * (1 + offset), TRUTH["scoat_gpa"], TRUTH["tcoat_mm"]])

    def no_least_squares(*args, **kwargs):
        raise AssertionError("near: no least_squares run")

    usual = local_fit(ResidualModel(problem, SolverRuns(problem, tmp_path / "a", jobs=1)), start)
    monkeypatch.setattr(_local, "least_squares", no_least_squares)
    runs = SolverRuns(problem, tmp_path / "b", jobs=1)
    said: list[str] = []
    fit = local_fit(ResidualModel(problem, runs), start, near=True, say=said.append)
    assert fit.converged, fit.message
    # a line for each round whose test did not hold: where it goes on, the runs so far
    pattern = r"local phase round (\d+): RMSE [0-9.e+-]+ N after (\d+) solver runs; \S"
    matches = [re.fullmatch(pattern, line[: line.index("; ") + 3]) for line in said]
    assert said or offset == 0.0  # off the optimum, the first round goes on from a step
    assert all(matches), said
    assert [int(m.group(1)) for m in matches] == list(range(1, len(said) + 1))
    assert all(int(m.group(2)) <= runs.calls for m in matches)
    p, G = len(start), len(problem.groups)
    rounds = 3  # each: a Jacobian (p·G runs) and at most the four backtracked steps
    assert runs.calls <= 1 * G + rounds * (p * G + len(_local.BACKTRACK) * G)
    resolution = _local.gain_tolerance(problem.n_points, p, _local.ROUGH_CHI2)
    assert fit.rmse <= usual.rmse * (1 + resolution)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_fit_names_the_runs_it_was_evaluated_with(tmp_path, seed):
    """The fit's parameters are those its curves were run at, to the last bit, wherever
    its point came from (``best_evaluated`` rebuilds x from a rounded memo key): their
    result-cache keys name the cached runs, so a resumed calibration repeats no run.
    Before, a point a finite-difference Jacobian had run came back an ulp away."""
    problem = _problem(tmp_path, seed)
    runs = SolverRuns(problem, tmp_path / "cache", jobs=1)
    model = ResidualModel(problem, runs)
    rng = np.random.default_rng(seed)
    start = np.array([TRUTH["ecoat_gpa"], TRUTH["scoat_gpa"], TRUTH["tcoat_mm"]])
    x = model.pin(start)
    model.jacobian(x)  # runs at x and at a shifted point per coordinate
    for _ in range(5):
        x = np.clip(x + rng.uniform(-0.05, 0.05, x.size) / 3.0 * np.pi, 0.0, 1.0)
        model.evaluate(x)
    rebuilt = model.best_evaluated()
    assert rebuilt is not None
    theta = model.point(rebuilt)
    keys = model.keys(theta)
    assert all(runs.cache.get(key) is not None for key in keys)
    assert set(keys) <= runs.used
    calls = runs.calls
    model.evaluate(rebuilt)
    assert runs.calls == calls


@pytest.mark.parametrize(
    ("script", "converged", "tests"),
    [
        ("gggggh", True, 6),  # five verified gains in a row: more than ROUNDS, none a stall
        ("sgsgsgh", True, 7),  # three stalls, below ROUNDS
        ("ssss", False, 4),  # ROUNDS stalls: given up
        ("gsgsgsgsh", False, 8),  # the fourth stall ends it, whatever the gains between
    ],
)
def test_only_rounds_without_a_verified_gain_count_against_the_limit(
    tmp_path, monkeypatch, script, converged, tests
):
    """A round whose step the solver verified is progress (a fit crawling along a valley
    goes on while the budget lasts); ``ROUNDS`` rounds whose test found no better point
    end the fit unconverged (the first-order test scripted: g a verified gain, s a
    stall, h holds)."""
    problem = _problem(tmp_path, 0)
    start = np.array([TRUTH["ecoat_gpa"], TRUTH["scoat_gpa"], TRUTH["tcoat_mm"]])
    calls = []

    def scripted(model, x):
        kind = script[len(calls)]
        calls.append(kind)
        return _local._FirstOrderTest(
            kind == "h", 0.01, 0.005 if kind == "g" else None, x, f"scripted {kind}"
        )

    monkeypatch.setattr(_local, "_first_order_test", scripted)
    runs = SolverRuns(problem, tmp_path / "c", jobs=1)
    fit = local_fit(ResidualModel(problem, runs), start, near=True)
    assert _local._ROUNDS == 4
    assert len(calls) == tests
    assert fit.converged is converged
    assert fit.message == (
        "scripted h" if converged else "not at a verified local optimum: scripted s"
    )


@pytest.mark.parametrize("margin", [0.0, 2e-4, 1e-3])
@pytest.mark.parametrize(("name", "side"), [("scoat_gpa", -1), ("ecoat_gpa", -1), ("ecoat_gpa", 1)])
def test_a_difference_step_takes_no_coat_past_a_bound_it_lies_inside(tmp_path, name, side, margin):
    """Within a step of Ecoat's or Scoat's bound but inside it, every shifted run of a
    Jacobian stays inside the ranges: a Tcoat step at fixed D and Mp had taken Scoat past
    its lower bound, where the range held it — a kinked slope, and Mp's 95 % interval
    ±64 % where the curves fix it to ±0.03 % (*early-yield-n2* seed 1 of
    ``benchmarks/calibration.py`` with OpenBLAS's Haswell kernels on an AVX-512 EPYC). At
    the bound itself (``margin`` 0) the differences are the held ones, as before: the
    Tcoat step that pushes the coat outwards keeps it at the bound."""
    problem = _problem(tmp_path, 0)
    space, k = problem.space, list(problem.space.names).index(name)
    spec = space[name]
    theta = np.array([TRUTH[n] for n in space.names])
    theta[k] = spec.low * (1 + margin) if side < 0 else spec.high * (1 - margin)
    model = ResidualModel(problem, SolverRuns(problem, tmp_path / "cache", jobs=1))
    model.jacobian(model.pin(theta))
    values = [float(point[k]) for point, _ in model.evaluated()]
    assert len(values) == 1 + theta.size  # the point and one shift a coordinate, all run
    if margin:
        # not at a bound to rounding (a clipped value can come back an ulp inside it)
        assert all(spec.low * (1 + 1e-9) < v < spec.high * (1 - 1e-9) for v in values), values
    else:  # held: the point and the Tcoat step (outwards at fixed D or Mp) at the bound
        assert sum(v == pytest.approx(spec.low if side < 0 else spec.high) for v in values) >= 2


@pytest.mark.parametrize(
    ("name", "side"), [("ecoat_gpa", -1), ("ecoat_gpa", 1), ("scoat_gpa", -1), ("scoat_gpa", 1)]
)
def test_the_declared_jacobian_at_a_held_modulus_is_its_difference_in_the_declared_units(
    tmp_path, name, side
):
    """``∂r/∂u`` at Ecoat or Scoat on a bound is the slope along the declared coordinates
    (the modulus held there): each column within 2 % of a forward difference in ``u``.
    Tcoat's column had counted the section's change twice at a lower bound, where the Tcoat
    step at fixed D or Mp pushes the modulus outwards (norm 315 against 157)."""
    problem = _problem(tmp_path, 0)
    space, k = problem.space, list(problem.space.names).index(name)
    theta = np.array([TRUTH[n] for n in space.names])
    theta[k] = space[name].low if side < 0 else space[name].high
    model = ResidualModel(problem, SolverRuns(problem, tmp_path / "cache", jobs=1))
    unit = np.clip(space.to_unit(theta[None, :])[0], 0.0, 1.0)
    jac = model.unit_jacobian(unit)
    at = model.residual(model.coordinates.from_unit(unit))
    for j in range(unit.size):
        step = 1e-5 if unit[j] + 1e-5 <= 1.0 else -1e-5
        moved = unit.copy()
        moved[j] += step
        direct = (model.residual(model.coordinates.from_unit(moved)) - at) / step
        scale = max(np.linalg.norm(direct), 1e-9 * np.linalg.norm(jac))
        assert np.linalg.norm(jac[:, j] - direct) <= 0.02 * scale, (
            space.names[j],
            jac[:, j],
            direct,
        )


def test_at_a_corner_a_difference_keeps_its_side_where_the_other_leaves_the_box(tmp_path):
    """Tcoat at its lower bound and Scoat 0.1 % above its own: the Tcoat step up would take
    Scoat past its bound, and the step down would leave the box, where the range holds
    Tcoat and the difference is zero. The step keeps its side: the bound's kink rather
    than no slope at all."""
    problem = _problem(tmp_path, 0)
    names = list(problem.space.names)
    theta = np.array([TRUTH[n] for n in names])
    theta[names.index("tcoat_mm")] = problem.space["tcoat_mm"].low
    theta[names.index("scoat_gpa")] = problem.space["scoat_gpa"].low * 1.001
    model = ResidualModel(problem, SolverRuns(problem, tmp_path / "cache", jobs=1))
    jac = model.jacobian(model.pin(theta))
    norms = np.linalg.norm(jac, axis=0)  # every column a slope, not rounding (an ulp apart)
    assert np.all(norms > 1e-6 * norms.max()), norms


@pytest.mark.parametrize("short", [1, 3])
def test_a_round_whose_jacobian_the_budget_cannot_hold_spends_none_of_it(tmp_path, short):
    """The first-order test's Jacobian (p points × G runs) is started only where the budget
    left holds it: a Jacobian that cannot finish tells nothing (an expensive local phase
    spent its last 2 CalculiX runs, 3 minutes, on one). With a budget ``short`` runs
    below the start and its Jacobian, the fit stops at the start with runs unspent; with
    enough for them, the same test runs."""
    problem = _problem(tmp_path, 0)
    start = np.array([TRUTH["ecoat_gpa"] * 1.02, TRUTH["scoat_gpa"], TRUTH["tcoat_mm"]])
    G = len(TESTS)
    needed = (1 + start.size) * G  # the start and one point a column, at every group
    runs = SolverRuns(problem, tmp_path / "short", jobs=1)
    fit = local_fit(ResidualModel(problem, runs, budget=needed - short), start, near=True)
    assert runs.calls == G  # the start only: no column of a Jacobian
    assert not fit.converged and "the first-order test's Jacobian needs" in fit.message
    assert fit.budget_spent  # the calibration says budget_exhausted, "raise --budget"
    assert np.array_equal(fit.theta, start)
    enough = SolverRuns(problem, tmp_path / "enough", jobs=1)
    local_fit(ResidualModel(problem, enough, budget=needed + G), start, near=True)
    assert enough.calls > needed - short  # the Jacobian ran


def test_a_test_that_finds_nothing_better_costs_no_second_jacobian(tmp_path, monkeypatch):
    """Where no fraction of the Gauss–Newton step delivers what it promised, the difference
    step shrinks for a next round only: the fit's own Jacobian is the test's, whose runs
    are done. It had been taken again at the smaller step, p × G more runs — 6 CalculiX
    runs where the expensive solver's test at a stall found nothing better."""
    problem = _problem(tmp_path, 0)
    G, p = len(TESTS), 3
    uphill = np.full(p, 0.04)  # a promise the solver does not keep: away from the truth

    monkeypatch.setattr(_local, "gauss_newton_step", lambda residual, jac, unit: (uphill, 0.5))
    runs = SolverRuns(problem, tmp_path / "runs", jobs=1)
    start = np.array([TRUTH["ecoat_gpa"], TRUTH["scoat_gpa"], TRUTH["tcoat_mm"]])
    fit = _local.optimum_test(ResidualModel(problem, runs, budget=100), start)
    assert not fit.converged and "the Jacobian is not trusted" in fit.message, fit.message
    assert runs.calls == G * (1 + p + len(_local.BACKTRACK))  # the point, its columns, the steps
    assert np.all(np.isfinite(fit.jacobian))


def test_a_verified_point_keeps_its_runs_through_the_fit_coordinates():
    """A point pinned to its parameters stays that point through :meth:`canonical` to the
    bit wherever its moduli lie within their ranges (the round trip through the unit
    coordinates had moved 12 % of them by an ulp, and a local fit started at a verified
    point then ran its runs again); where a modulus is held, the point moves onto its
    bound's coordinate, its other coordinates stay, and moving it again changes nothing."""
    from surrogate.calibration._local import FitCoordinates
    from surrogate.study._space import PAPER_SPACE

    coordinates = FitCoordinates(PAPER_SPACE, 1.2)
    names = list(PAPER_SPACE.names)
    rng = np.random.default_rng(7)
    for unit in rng.random((2000, 3)):
        theta = PAPER_SPACE.from_unit(unit[None])[0]
        x = np.clip(coordinates.from_unit(PAPER_SPACE.to_unit(theta[None])[0]), 0.0, 1.0)
        assert np.array_equal(coordinates.canonical(x), x)
    index = {"ecoat_gpa": coordinates.ie, "scoat_gpa": coordinates.is_}
    for name, side in [("ecoat_gpa", -1.0), ("scoat_gpa", 1.0), ("scoat_gpa", -1.0)]:
        spec = PAPER_SPACE[name]
        for unit in rng.random((50, 3)):
            unit[names.index(name)] = 0.0 if side < 0 else 1.0
            x = coordinates.from_unit(unit)
            x[index[name]] = np.clip(x[index[name]] + side * rng.uniform(0.001, 0.05), 0.0, 1.0)
            held = coordinates.canonical(x)
            assert not np.array_equal(held, x)
            assert np.array_equal(coordinates.canonical(held), held)
            assert np.array_equal(np.delete(held, index[name]), np.delete(x, index[name]))
            theta = PAPER_SPACE.from_unit(coordinates.to_unit(held)[None])[0]
            bound = spec.low if side < 0 else spec.high
            assert theta[names.index(name)] == pytest.approx(bound, rel=1e-12)
