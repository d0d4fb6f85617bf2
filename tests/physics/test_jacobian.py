"""The Newton Jacobian of the rod solver against central finite differences, and
Newton's condensed linear solve against a dense one."""

import numpy as np
import pytest

from surrogate.physics import CoatingSection, default_mesh, uniform_mesh
from surrogate.physics._rod import _march, _Problem

L, B = 10.0, 38.0


def _converged_at(problem, angle_deg):
    """The converged configuration after rotating the clamp to ``angle_deg``."""
    *_, (_, current) = _march(problem, np.radians(np.arange(1.0, angle_deg + 0.5)))
    return current


def _check(problem, previous, psi, lam, theta):
    ev = problem.evaluate(psi, lam, theta, previous)
    analytic = problem.jacobian(ev)
    x = np.concatenate([psi, [lam]])
    numeric = np.empty_like(analytic)
    step = 1e-7
    for j in range(x.size):
        plus, minus = x.copy(), x.copy()
        plus[j] += step
        minus[j] -= step
        numeric[:, j] = (
            problem.evaluate(plus[:-1], plus[-1], theta, previous).residual
            - problem.evaluate(minus[:-1], minus[-1], theta, previous).residual
        ) / (2 * step)
    # Central differences: truncation ~1e-14 relative, round-off ~1e-9.
    np.testing.assert_allclose(analytic, numeric, atol=1e-6 * np.max(np.abs(analytic)))
    # Newton's step condenses the tridiagonal tail onto the contact's head: the
    # same solution as a dense LU, to round-off times the condition number
    # (at most ~3e6 here, with the sticking penalty) of the step's largest entry.
    dense = np.linalg.solve(analytic, -ev.residual)
    condensed = problem.jacobian_parts(ev).solve(-ev.residual)
    np.testing.assert_allclose(condensed, dense, rtol=0, atol=1e-9 * np.max(np.abs(dense)))
    return ev


@pytest.mark.parametrize(
    ("mesh", "section", "mu", "angle", "tension", "expect"),
    [
        (default_mesh(35, L), CoatingSection(1000, 1e9, 0.012, 1.2), 0.2, 30, 0.0, "sliding"),
        (default_mesh(35, L), CoatingSection(1000, 1e9, 0.012, 1.2), 0.0, 50, 20.0, "segment"),
        (default_mesh(35, L), CoatingSection(4000, 50, 0.05, 1.2), 0.1, 30, 0.0, "sticking"),
        (uniform_mesh(35, 2.5), CoatingSection(1000, 1e9, 0.012, 1.2), 0.1, 45.5, 0.0, "vertex"),
    ],
)
def test_jacobian_matches_finite_differences(mesh, section, mu, angle, tension, expect):
    problem = _Problem(
        section,
        mesh,
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=1.6,
        friction=mu,
        tension_n=tension,
    )
    previous = _converged_at(problem, angle - 1)
    # An iterate near, not at, the solution of the next step.
    rng = np.random.default_rng(0)
    noise = 0.0 if expect == "sticking" else 1e-3  # any slip at all would end sticking
    psi = previous.psi + noise * rng.standard_normal(problem.N)
    if expect == "vertex":
        # The probe crosses nodes where the moment is zero, so converged states
        # have no kink there. Turn the contact segment so that the probe centre
        # projects past its end and kink the strip at that node: the probe then
        # sits in the wedge of a convex kink, the vertex branch.
        k = problem.evaluate(
            previous.psi, previous.lam, np.radians(angle), previous
        ).contact.segment
        psi[k] += 0.02
        psi[k + 1 :] -= 0.08
    ev = _check(problem, previous, psi, previous.lam * 1.01, np.radians(angle))
    if expect == "vertex":
        assert ev.contact.on_vertex
    elif expect == "sticking":
        assert ev.sticking
    elif expect == "sliding":
        assert not ev.sticking and ev.friction_n != 0.0
    else:
        assert not ev.contact.on_vertex


@pytest.mark.parametrize(
    ("line_load", "spring", "mu", "angle"),
    [
        (2e-3, None, 0.1, 30),  # self-weight, in contact
        (0.0, 200.0, 0.1, 30),  # compliant clamp
        (2e-3, 200.0, 0.0, 40),  # both
    ],
)
def test_jacobian_with_self_weight_and_clamp_spring(line_load, spring, mu, angle):
    problem = _Problem(
        CoatingSection(1000, 200, 0.012, 1.2),
        default_mesh(35, L),
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=1.6,
        friction=mu,
        tension_n=0.0,
        line_load_n_mm=line_load,
        clamp_stiffness_nmm=spring,
    )
    previous = _converged_at(problem, angle - 1)
    assert problem.active
    psi = previous.psi + 1e-3 * np.random.default_rng(1).standard_normal(problem.N)
    _check(problem, previous, psi, previous.lam * 1.01, np.radians(angle))


def test_jacobian_of_a_free_strip_under_self_weight():
    problem = _Problem(
        CoatingSection(50, 10, 0.012, 1.2),
        default_mesh(35, L),
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=1.6,
        friction=0.1,
        tension_n=0.0,
        line_load_n_mm=5e-3,
    )
    previous = _converged_at(problem, 1)
    assert not problem.active  # a soft strip still hangs below the probe at 1°
    psi = previous.psi + 1e-3 * np.random.default_rng(2).standard_normal(problem.N)
    ev = _check(problem, previous, psi, 0.0, np.radians(2))
    assert ev.gap > 0
