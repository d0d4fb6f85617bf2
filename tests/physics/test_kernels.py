"""The compiled pieces of the rod solver against plain numpy references.

The section law against the vectorised return mapping it replaced (ed0e605);
the two linear solvers of Newton's step on systems that need row interchanges
and on singular ones; the load-step predictor on paths it must extrapolate
exactly.
"""

import itertools

import numpy as np
import pytest

from surrogate.physics import CoatingSection
from surrogate.physics._rod import _dense_solve, _Predictor, _tridiagonal_solve


def _vectorised_respond(section, kappa, eps_p):
    """The section law as ed0e605 wrote it, with numpy over all points and fibres."""
    E, S, H, D0, z, moment_arm, tangent_arm = section.fibres  # arms: 2·z·w, 2·z²·w
    strain = kappa[:, None] * z[None, :]
    relative = E * (strain - eps_p) - H * eps_p
    excess = np.abs(relative) - S
    plastic = excess > 0.0
    eps_p_new = eps_p + np.where(plastic, excess / (E + H), 0.0) * np.sign(relative)
    stress = E * (strain - eps_p_new)
    modulus = np.where(plastic, E * H / (E + H), E)
    moment = stress @ moment_arm + D0 * kappa
    tangent = modulus @ tangent_arm + D0
    return moment, tangent, eps_p_new


@pytest.mark.parametrize(("hardening", "extra"), [(0.0, 0.0), (60.0, 0.0), (0.0, 3.0)])
def test_return_mapping_matches_the_vectorised_law(hardening, extra):
    section = CoatingSection(
        1000.0, 200.0, 0.05, 1.2, hardening_modulus_mpa=hardening, extra_stiffness_nmm=extra
    )
    rng = np.random.default_rng(3)
    kappa = rng.uniform(-1.5, 1.5, 40)  # from elastic to fully plastic both ways
    eps_p = rng.uniform(-0.3, 0.3, (40, section.n_fibres)) * (rng.random((40, 1)) < 0.5)
    moment, tangent, state = section.respond(kappa, type(section.initial_state(1))(eps_p))
    expected = _vectorised_respond(section, kappa, eps_p)
    # Only the order of the sums differs: round-off.
    np.testing.assert_allclose(moment, expected[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tangent, expected[1], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(state.eps_p, expected[2])


def _tridiagonal(diag, off):
    return np.diag(diag) + np.diag(off, 1) + np.diag(off, -1)


def test_tridiagonal_solve_interchanges_rows_where_the_diagonal_is_small():
    rng = np.random.default_rng(4)
    diag, off = rng.uniform(-0.1, 0.1, 12), rng.uniform(1.0, 2.0, 11)
    rhs = rng.standard_normal((12, 2))
    expected = np.linalg.solve(_tridiagonal(diag, off), rhs)
    assert _tridiagonal_solve(off, diag, rhs)
    np.testing.assert_allclose(rhs, expected, rtol=1e-10, atol=1e-12)


def test_tridiagonal_solve_reports_a_singular_system():
    # Two segments joined by a spring, neither held: a free rotation (det = 0).
    diag, off = np.array([1.0, 1.0]), np.array([-1.0])
    assert not _tridiagonal_solve(off, diag, np.ones((2, 2)))


def test_dense_solve_pivots_and_reports_a_singular_matrix():
    rng = np.random.default_rng(5)
    matrix = rng.standard_normal((7, 7))
    matrix[0, 0] = 0.0  # no LU without a row interchange
    rhs = rng.standard_normal(7)
    expected = np.linalg.solve(matrix, rhs)
    a, b = matrix.copy(), rhs.copy()
    assert _dense_solve(a, b)
    np.testing.assert_allclose(b, expected, rtol=1e-10, atol=1e-12)
    singular = matrix.copy()
    singular[3] = 2.0 * singular[1]
    assert not _dense_solve(singular, rhs.copy())


class _Step:
    """A converged state as the predictor reads it."""

    def __init__(self, psi, lam):
        self.psi, self.lam = psi, lam


@pytest.mark.parametrize("degree", [1, 2])
def test_predictor_extrapolates_linear_and_quadratic_paths_exactly(degree):
    """After three steps the predictor has seen which guess fits: a linear path
    is extrapolated linearly, a quadratic one quadratically, both exactly (to
    round-off), also across unequal steps."""
    coefficients = np.array([[0.3, -1.2, 0.5], [0.7, 0.4, -2.0], [1.5, 2.0, 0.9]])

    def state(theta):
        powers = theta ** np.arange(3)
        values = coefficients[:, : degree + 1] @ powers[: degree + 1]
        return _Step(values[:-1].copy(), float(values[-1]))

    predictor = _Predictor(3)
    thetas = [0.0, 0.02, 0.05, 0.06]
    for before, after in itertools.pairwise(thetas):
        predictor.update(state(before), state(after), after - before)
    psi, lam = predictor.guess(state(0.06).psi, state(0.06).lam, 0.03)
    target = state(0.09)
    np.testing.assert_allclose(psi, target.psi, rtol=1e-12, atol=1e-14)
    assert lam == pytest.approx(target.lam, rel=1e-12)
    if degree == 2:
        assert predictor.quadratic


def test_a_singular_initial_stiffness_matrix_fails_the_step_without_a_warning(monkeypatch):
    """The initial-stiffness fallback on a singular matrix: the step fails (bisection
    takes over) and nothing reaches the user's stderr (SciPy's ``lu_factor``, which the
    fallback called before it called LAPACK's ``getrf`` itself, only warned there, and a
    benchmark run printed its LinAlgWarning)."""
    import warnings

    from surrogate.physics import default_mesh
    from surrogate.physics._rod import _initial_stiffness, _Problem

    section = CoatingSection(1000.0, 200.0, 0.012, 1.2)
    problem = _Problem(
        section,
        default_mesh(35.0, 15.0),
        width_mm=25.0,
        bending_length_mm=15.0,
        contact_radius_mm=1.6,
        friction=0.1,
        tension_n=0.0,
    )
    rest = problem.configuration(np.zeros(problem.N), 0.0, section.initial_state(problem.N), 0.0)
    jacobian = problem.jacobian

    def singular(ev, stiff=None):
        matrix = jacobian(ev, stiff)
        matrix[5] = 0.0
        return matrix

    monkeypatch.setattr(problem, "jacobian", singular)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _initial_stiffness(problem, rest.psi, 0.0, np.radians(10.0), rest) is None
