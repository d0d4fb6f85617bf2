"""The built-in solver against the verification tables of design.md §3.

Tolerance 0.5 % everywhere: the product's accuracy target at the default
discretisation. The solver's own discretisation error there is about 0.08 %
(second order in the element size, see test_convergence.py); the point probe is
modelled as a probe of radius 1e-3 mm (1e-4·l), whose effect is far below that.
"""

import numpy as np
import pandas as pd
import pytest

from surrogate.physics import (
    CoatingSection,
    default_mesh,
    solve_cantilever,
    solve_rod,
    uniform_mesh,
)

RTOL = 5e-3
L, B, T = 10.0, 38.0, 1.2
POINT_PROBE_MM = 1e-3


def _elastic(ecoat=1000.0, tcoat=0.012):
    return CoatingSection(ecoat, 1e9, tcoat, T)  # yield stress far out of reach


def _point_probe_run(section, mu, angles):
    return solve_rod(
        section,
        angles,
        segment_lengths_mm=default_mesh(35.0, L),
        width_mm=B,
        bending_length_mm=L,
        contact_radius_mm=POINT_PROBE_MM,
        friction=mu,
    )


@pytest.fixture(scope="module")
def elastica(reference_dir):
    return pd.read_csv(reference_dir / "elastica.csv", comment="#")


@pytest.mark.parametrize("mu", [0.0, 0.2, 0.4])
def test_elastica_table(elastica, mu):
    table = elastica[elastica.mu == mu]
    section = _elastic()
    unit = section.stiffness_nmm * B / L**2  # EI/l²
    angles = np.concatenate(([0.0], table.angle_deg.to_numpy()))
    run = _point_probe_run(section, mu, angles)
    np.testing.assert_allclose(run.normal_force_n[1:] / unit, table.normal, rtol=RTOL)
    np.testing.assert_allclose(run.force_n[1:] / unit, table.resultant, rtol=RTOL)
    np.testing.assert_allclose(run.force_perp_n[1:] / unit, table.perp, rtol=RTOL)
    np.testing.assert_allclose(run.contact_arc_mm[1:] / L, table.contact_arc, rtol=RTOL)
    np.testing.assert_allclose(run.clamp_moment_nmm[1:] / (unit * L), table.clamp_moment, rtol=RTOL)


def test_small_angle_formula():
    section = _elastic()
    angles = np.array([0.0, 0.25, 0.5, 1.0])
    run = _point_probe_run(section, 0.0, angles)
    expected = 3 * section.stiffness_nmm * B * np.radians(angles[1:]) / L**2
    np.testing.assert_allclose(run.force_n[1:], expected, rtol=RTOL)


def test_cantilever_table(reference_dir):
    table = pd.read_csv(reference_dir / "cantilever.csv", comment="#")
    section = _elastic()
    length, width = 20.0, 10.0
    EI = section.stiffness_nmm * width
    tips, rotation = solve_cantilever(
        section,
        table.alpha.to_numpy() * EI / length**2,
        segment_lengths_mm=uniform_mesh(length, length / 50),
        width_mm=width,
    )
    np.testing.assert_allclose(tips[:, 0] / length, table.w_over_L, rtol=RTOL)
    np.testing.assert_allclose(tips[:, 1] / length, table.u_over_L, rtol=RTOL)
    np.testing.assert_allclose(rotation, table.tip_rotation_rad, rtol=RTOL)


def test_rigid_plastic_limit():
    # Stiff coat, low yield: a hinge forms at the clamp within a degree or two,
    # then the perpendicular force stays at b·Mp/l (moment balance about the clamp).
    section = CoatingSection(400_000.0, 50.0, 0.05, T)
    angles = np.arange(0.0, 91.0, 1.0)
    run = _point_probe_run(section, 0.0, angles)
    limit = B * section.plastic_moment_nmm / L
    np.testing.assert_allclose(run.force_perp_n[angles >= 10], limit, rtol=RTOL)
    assert np.all(run.force_perp_n <= limit * (1 + 1e-6))
