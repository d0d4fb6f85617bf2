"""The coating's moment–curvature law against design.md's closed forms."""

import numpy as np
import pytest

from surrogate.physics import CoatingSection, bending_stiffness, plastic_moment

T = 1.2


def _section(**kw):
    args = dict(ecoat_mpa=1000.0, scoat_mpa=200.0, tcoat_mm=0.05, thickness_mm=T)
    args.update(kw)
    return CoatingSection(**args)


def _load_path(section, kappas):
    """Moments along a curvature history at one material point."""
    state = section.initial_state(1)
    moments = []
    for kappa in kappas:
        m, _, state = section.respond(np.array([kappa]), state)
        moments.append(m[0])
    return np.array(moments), state


@pytest.mark.parametrize("tcoat", [0.005, 0.012, 0.05, 0.1, 0.3])
def test_closed_forms_of_design_md(tcoat):
    z2, z1 = T / 2, T / 2 - tcoat
    assert bending_stiffness(1000.0, tcoat, T) == pytest.approx(2 / 3 * 1000.0 * (z2**3 - z1**3))
    assert plastic_moment(200.0, tcoat, T) == pytest.approx(200.0 * (z2**2 - z1**2))
    # the thin-coat approximation D ≈ E·Tcoat·t²/2 holds to O(Tcoat/t)
    thin = 1000.0 * tcoat * T**2 / 2
    assert bending_stiffness(1000.0, tcoat, T) == pytest.approx(thin, rel=2.1 * tcoat / T)


@pytest.mark.parametrize("tcoat", [0.01, 0.05, 0.1])
def test_elastic_slope_is_D_exactly(tcoat):
    section = _section(tcoat_mm=tcoat)
    kappa_yield = 200.0 / (1000.0 * T / 2)
    kappa = np.linspace(-0.99, 0.99, 7) * kappa_yield
    m, c, _ = section.respond(kappa, section.initial_state(kappa.size))
    D = bending_stiffness(1000.0, tcoat, T)
    # Gauss–Legendre fibres integrate z² exactly: agreement to round-off.
    np.testing.assert_allclose(m, D * kappa, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(c, D, rtol=1e-12)


@pytest.mark.parametrize("tcoat", [0.01, 0.05, 0.1])
def test_fully_plastic_moment_is_Mp_exactly(tcoat):
    section = _section(tcoat_mm=tcoat)
    kappa_full = 200.0 / (1000.0 * (T / 2 - tcoat))  # innermost coat fibre yields
    m, c, _ = section.respond(
        np.array([1.01 * kappa_full, -3 * kappa_full]), section.initial_state(2)
    )
    Mp = plastic_moment(200.0, tcoat, T)
    np.testing.assert_allclose(m, [Mp, -Mp], rtol=1e-12)
    np.testing.assert_allclose(c, 0.0, atol=1e-12)


def test_transition_between_first_yield_and_Mp_is_monotone():
    section = _section(tcoat_mm=0.1)
    kappas = np.linspace(0.0, 0.6, 301)
    m, _ = _load_path(section, kappas)
    D = bending_stiffness(1000.0, 0.1, T)
    Mp = plastic_moment(200.0, 0.1, T)
    assert np.all(np.diff(m) >= -1e-12)
    assert np.all(m <= np.minimum(D * kappas, Mp) + 1e-9)  # below both bounds
    first_yield = 200.0 / (1000.0 * T / 2)
    np.testing.assert_allclose(m[kappas < first_yield], D * kappas[kappas < first_yield])


def test_unloading_is_elastic_from_the_stored_plastic_curvature():
    section = _section(tcoat_mm=0.05)
    D = bending_stiffness(1000.0, 0.05, T)
    Mp = plastic_moment(200.0, 0.05, T)
    kappa_max = 2.0
    m, state = _load_path(section, np.linspace(0, kappa_max, 50))
    assert m[-1] == pytest.approx(Mp)
    # stored plastic curvature: zero-moment curvature after elastic unloading
    kappa_p = section.plastic_curvature(state)[0]
    assert kappa_p == pytest.approx(kappa_max - Mp / D, rel=1e-10)
    unload = np.linspace(kappa_max, kappa_p, 11)
    m_un, c_un, _ = section.respond(unload, type(state)(np.repeat(state.eps_p, 11, axis=0)))
    np.testing.assert_allclose(m_un, D * (unload - kappa_p), atol=1e-9 * Mp)
    # strictly inside the elastic range (the first point is still on the yield surface)
    np.testing.assert_allclose(c_un[1:], D)


def test_reverse_yield_after_elastic_range_of_outer_fibre():
    section = _section(tcoat_mm=0.05)
    m, _ = _load_path(section, np.concatenate([np.linspace(0, 2, 40), np.linspace(2, -2, 200)]))
    Mp = plastic_moment(200.0, 0.05, T)
    assert m.min() == pytest.approx(-Mp)  # ideal plasticity: symmetric limit


def test_linear_hardening_tangent():
    E, ratio = 1000.0, 0.05
    Et = ratio * E
    H = E * Et / (E - Et)  # plastic modulus giving a post-yield tangent Et
    section = _section(tcoat_mm=0.05, hardening_modulus_mpa=H)
    kappa_full = 200.0 / (1000.0 * (T / 2 - 0.05))
    _, c, _ = section.respond(np.array([3 * kappa_full]), section.initial_state(1))
    assert c[0] == pytest.approx(bending_stiffness(Et, 0.05, T), rel=1e-12)
    # before first yield hardening changes nothing
    m0, _, _ = _section().respond(np.array([0.1]), _section().initial_state(1))
    m1, _, _ = section.respond(np.array([0.1]), section.initial_state(1))
    assert m1[0] == m0[0]
