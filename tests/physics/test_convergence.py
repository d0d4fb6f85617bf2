"""Mesh convergence of the built-in solver and the coarse-mesh option."""

import numpy as np
import pytest

import surrogate
from surrogate.physics import CoatingSection, default_mesh, solve_rod

L, B = 10.0, 38.0


def _f60(section, mesh, *, mu=0.1, rho=1.6):
    run = solve_rod(
        section,
        np.arange(0.0, 61.0),
        segment_lengths_mm=mesh,
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=rho,
        friction=mu,
    )
    return run.force_n[-1]


@pytest.mark.parametrize(
    ("ecoat", "scoat", "tcoat"),
    [(1000.0, 200.0, 0.012), (2000.0, 200.0, 0.05)],  # elastic; yields near the clamp
)
def test_observed_order_and_default_error(ecoat, scoat, tcoat):
    section = CoatingSection(ecoat, scoat, tcoat, 1.2)
    fractions = [1 / 12.5, 1 / 25, 1 / 50, 1 / 200]
    f60 = np.array([_f60(section, default_mesh(35.0, L, fine_fraction=f)) for f in fractions])
    reference = f60[-1]  # 8× finer than the default
    errors = np.abs(f60[:-1] / reference - 1.0)
    orders = np.log2(errors[:-1] / errors[1:])
    print(
        f"\nF60 relative error at h = l/12.5, l/25 (default), l/50: {errors}; "
        f"observed orders {orders}"
    )
    assert errors[1] < 5e-3, "default discretisation must be within 0.5 %"
    assert np.all(orders > 1.5), f"expected about second order, observed {orders}"


def test_coarse_system_model_mesh_changes_the_curve_visibly():
    fine = surrogate.simulate(1.0, 0.2, 0.012)
    coarse = surrogate.simulate(1.0, 0.2, 0.012, rig=surrogate.Rig(element_size_mm=2.5))
    assert np.all(np.isfinite(coarse.force_n))
    difference = np.max(np.abs(coarse.force_n - fine.force_n)) / fine.f60_n
    assert 0.005 < difference < 0.5  # visible but the same test
