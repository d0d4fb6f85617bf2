"""The public ``simulate`` API: the paper's physics observations, inputs, failures."""

import subprocess
import sys

import numpy as np
import pytest

import surrogate
from surrogate.physics import bending_stiffness, solve_rod, uniform_mesh


def _elastic(ecoat, tcoat):
    return surrogate.simulate(ecoat, 100.0, tcoat)  # yield out of reach


def test_curve_has_whole_degrees_and_features():
    curve = surrogate.simulate(ecoat_gpa=1.0, scoat_gpa=0.2, tcoat_mm=0.012)
    np.testing.assert_array_equal(curve.angle_deg, np.arange(91.0))
    assert curve.force_n.shape == curve.force_perp_n.shape == (91,)
    assert curve.force_n[0] == 0.0
    assert curve.f60_n == pytest.approx(curve.force_n[60])
    assert np.all(curve.force_perp_n <= curve.force_n + 1e-12)
    # CalculiX (calculix.md, same rig) gives 9.98 N; the inextensible beam is
    # within a few per cent of the 3-D FE model.
    assert curve.f60_n == pytest.approx(9.98, rel=0.03)
    assert not curve.saturated and curve.theta_sat_deg == 90.0


def test_bending_stiffness_is_linear_in_ecoat():
    base, double = _elastic(1.0, 0.012), _elastic(2.0, 0.012)
    # The elastic problem scales exactly with D: only Newton's tolerance remains.
    np.testing.assert_allclose(double.force_n[1:], 2 * base.force_n[1:], rtol=1e-6)


def test_bending_stiffness_is_linear_in_tcoat():
    thin, thick = _elastic(1.0, 0.01), _elastic(1.0, 0.02)
    ratio = bending_stiffness(1000, 0.02, 1.2) / bending_stiffness(1000, 0.01, 1.2)
    np.testing.assert_allclose(thick.force_n[1:], ratio * thin.force_n[1:], rtol=1e-6)
    assert ratio == pytest.approx(2.0, rel=0.02)  # D ≈ E·Tcoat·t²/2, thin coat


def test_scoat_sets_the_saturation_force():
    low, high = surrogate.simulate(4.0, 0.05, 0.05), surrogate.simulate(4.0, 0.1, 0.05)
    assert low.saturated and high.saturated
    # Plateau ∝ Mp ∝ Scoat (the lever arm differs a little between the two).
    assert high.force_n[-1] / low.force_n[-1] == pytest.approx(2.0, rel=0.05)
    # before yield the two are the same curve
    np.testing.assert_allclose(low.force_n[:2], high.force_n[:2], rtol=1e-9)


def test_larger_scoat_to_ecoat_ratio_delays_saturation():
    angles = [surrogate.simulate(1.0, s, 0.05).theta_sat_deg for s in (0.025, 0.05, 0.1, 0.2)]
    assert angles == sorted(angles) and angles[0] < angles[-1]
    stiffer = [surrogate.simulate(e, 0.1, 0.05).theta_sat_deg for e in (0.5, 1.0, 2.0, 4.0)]
    assert stiffer == sorted(stiffer, reverse=True) and stiffer[0] > stiffer[-1]


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        (dict(ecoat_gpa=-1.0, scoat_gpa=0.2, tcoat_mm=0.012), "ecoat_gpa must be > 0"),
        (dict(ecoat_gpa=1.0, scoat_gpa=0.0, tcoat_mm=0.012), "scoat_gpa must be > 0"),
        (dict(ecoat_gpa=1.0, scoat_gpa=float("nan"), tcoat_mm=0.012), "finite"),
        (dict(ecoat_gpa=1.0, scoat_gpa=0.2, tcoat_mm=0.6), "tcoat_mm must be < thickness_mm/2"),
        (dict(ecoat_gpa=float("inf"), scoat_gpa=0.2, tcoat_mm=0.01), "finite"),
    ],
)
def test_bad_coating_values_are_refused(kwargs, fragment):
    with pytest.raises(surrogate.InputDataError, match=fragment):
        surrogate.simulate(**kwargs)


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        (dict(width_mm=0.0), "width_mm must be > 0"),
        (dict(friction=-0.1), "friction must be in"),
        (dict(max_angle_deg=120.0), "max_angle_deg must be in"),
        (dict(free_length_mm=15.0), "free_length_mm must be"),
        (dict(element_size_mm=0.0), "element_size_mm must be in"),
        (dict(tension_n=float("nan")), "finite"),
        (dict(thickness_mm="abc"), "must be a number"),
    ],
)
def test_bad_rig_values_are_refused(change, fragment):
    with pytest.raises(surrogate.InputDataError, match=fragment):
        surrogate.Rig(**change)


def test_tension_load_stiffens_the_response():
    free = surrogate.simulate(1.0, 0.2, 0.012)
    pulled = surrogate.simulate(1.0, 0.2, 0.012, rig=surrogate.Rig(tension_n=20.0))
    assert pulled.f60_n > 1.05 * free.f60_n
    np.testing.assert_allclose(pulled.force_n[0], 0.0)


def test_strip_sliding_off_the_probe_raises_solver_error():
    from surrogate.physics import CoatingSection

    short = uniform_mesh(10.5, 0.25)  # ends just past the probe
    with pytest.raises(surrogate.SolverError, match=r"slid off the probe at \d+\.\d\d°"):
        solve_rod(
            CoatingSection(1000, 200, 0.012, 1.2),
            np.arange(0.0, 91.0),
            segment_lengths_mm=short,
            width_mm=38,
            bending_length_mm=10,
            contact_radius_mm=1.6,
            friction=0.1,
        )


def test_error_types_subclass_builtins():
    assert issubclass(surrogate.InputDataError, ValueError)
    assert issubclass(surrogate.SolverError, RuntimeError)


def test_moving_plastic_hinge_converges():
    # Yields late (~80°): the moment peak, and with it the plastic hinge, moves
    # from node to node; plain Newton stalls there (see _initial_stiffness).
    curve = surrogate.simulate(0.9493146445486039, 0.15667183056099862, 0.03782233205831993)
    assert np.all(np.isfinite(curve.force_n)) and curve.force_n[-1] > curve.force_n[60]


def test_whole_paper_range_converges():
    from scipy.stats import qmc

    unit = qmc.LatinHypercube(d=3, seed=7).random(80)
    low, high = np.log([0.5, 0.05, 0.01]), np.log([4.0, 0.4, 0.1])
    for ecoat, scoat, tcoat in np.exp(low + unit * (high - low)):
        curve = surrogate.simulate(ecoat, scoat, tcoat)
        assert np.all(np.isfinite(curve.force_n)) and np.all(curve.force_n[1:] > 0)


def test_a_process_that_never_solves_does_not_load_the_compiled_rod():
    """numba (0.3–0.7 s an interpreter) loads with the first solve, not with
    ``import surrogate``, the CLI, the model state or an external solver's adapter:
    ``surrogate --help`` took 1.2 s, 0.4 s without it."""
    code = (
        "import sys, surrogate, surrogate._cli, surrogate.solvers, surrogate.calibration._problem\n"
        "from surrogate.solvers import model_state\n"
        "print('numba' in sys.modules)\n"
        "curve = surrogate.simulate(1.0, 0.2, 0.012)\n"
        "print('numba' in sys.modules, round(curve.f60_n, 6))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, after = done.stdout.splitlines()
    assert before == "False"
    expected = round(surrogate.simulate(1.0, 0.2, 0.012).f60_n, 6)
    assert after == f"True {expected}"
