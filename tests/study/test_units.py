"""Units of measured forces and angles: the conversion factors against their definitions,
and the unit a column's name states."""

import math

import numpy as np
import pytest

from surrogate import InputDataError
from surrogate.study._units import (
    ANGLE_UNITS,
    FORCE_UNITS,
    check_unit,
    to_degrees,
    to_newtons,
    unit_in_name,
)


def test_force_units_against_their_definitions():
    """Exact definitions: g₀ = 9.80665 m/s² (CGPM 1901), 1 lb = 0.45359237 kg (1959)."""
    forces = np.array([1.0, 250.0])
    np.testing.assert_array_equal(to_newtons(forces, "N"), forces)
    np.testing.assert_allclose(to_newtons(forces, "mN"), forces / 1000.0, rtol=1e-15)
    np.testing.assert_allclose(to_newtons(forces, "kN"), forces * 1000.0, rtol=1e-15)
    np.testing.assert_allclose(to_newtons(forces, "gf"), forces * 0.00980665, rtol=1e-15)
    np.testing.assert_allclose(to_newtons(forces, "kgf"), forces * 9.80665, rtol=1e-15)
    # the lbf as tables print it: 4.4482216152605 N
    np.testing.assert_allclose(to_newtons(forces, "lbf"), forces * 4.4482216152605, rtol=1e-14)
    assert set(FORCE_UNITS) == {"N", "mN", "kN", "gf", "kgf", "lbf"}


def test_angle_units():
    np.testing.assert_allclose(to_degrees(np.array([math.pi / 2, math.pi]), "rad"), [90, 180])
    assert to_degrees(45.0, "deg") == 45.0
    assert set(ANGLE_UNITS) == {"deg", "rad"}


def test_an_unknown_unit_names_the_key_and_the_known_ones():
    assert check_unit("force_unit", "mN", "force") == "mN"
    with pytest.raises(InputDataError, match=r"force_unit must be one of N, mN, .*got 'MN'"):
        check_unit("force_unit", "MN", "force")  # meganewton is not millinewton
    with pytest.raises(InputDataError, match="angle_unit must be one of deg, rad, got 'grad'"):
        check_unit("angle_unit", "grad", "angle")


@pytest.mark.parametrize(
    ("column", "quantity", "unit"),
    [
        ("force_n", "force", "N"),
        ("force_mn", "force", "mN"),
        ("force_kgf", "force", "kgf"),
        ("Force [mN]", "force", "mN"),
        ("Kraft (gf)", "force", "gf"),
        ("angle_rad", "angle", "rad"),
        ("Winkel [°]", "angle", "deg"),
        ("Angle [deg]", "angle", "deg"),
        ("Load", "force", None),
        ("force_perp_n", "force", None),  # not force_<unit>: says nothing
    ],
)
def test_the_unit_a_column_name_states(column, quantity, unit):
    assert unit_in_name(column, quantity) == unit


def test_a_bracketed_unit_that_is_not_known_is_refused():
    """Read as N, a column in cN would be 100× off: refused instead."""
    with pytest.raises(InputDataError, match=r"column 'Kraft \[cN\]' is in 'cN'.*convert"):
        unit_in_name("Kraft [cN]", "force")
    with pytest.raises(InputDataError, match="'MN'"):
        unit_in_name("Force [MN]", "force")
