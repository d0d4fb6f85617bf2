"""F60 and θsat: the single definition used for every curve."""

import numpy as np
import pytest

from surrogate import InputDataError
from surrogate.physics import curve_features


def test_linear_curve_never_saturates():
    angles = np.arange(91.0)
    features = curve_features(angles, 0.2 * angles)
    assert features.f60_n == pytest.approx(12.0)
    assert features.theta_sat_deg == 90.0 and not features.saturated


def test_plateau_found_where_the_5_degree_secant_drops_below_10_percent():
    angles = np.arange(91.0)
    force = np.minimum(angles, 40.0)  # slope 1 then flat from 40°
    features = curve_features(angles, force)
    # the secant over [θ, θ+5] is (40-θ)/5 < 0.1 first at θ = 40 - 0.5 → 40 on the grid
    assert features.theta_sat_deg == 40.0 and features.saturated
    soft = np.where(angles < 40, angles, 40 + 0.05 * (angles - 40))  # 5 % slope: saturated
    assert curve_features(angles, soft).theta_sat_deg == 40.0
    stiff = np.where(angles < 40, angles, 40 + 0.2 * (angles - 40))  # 20 % slope: not
    assert not curve_features(angles, stiff).saturated


def test_measured_curve_off_grid_and_not_from_zero():
    angles = np.linspace(0.7, 89.3, 200)
    features = curve_features(angles, 0.5 * angles)
    assert features.f60_n == pytest.approx(30.0)
    assert not features.saturated and features.theta_sat_deg == pytest.approx(89.3)


def test_short_curve_has_no_f60():
    features = curve_features(np.arange(45.0), np.arange(45.0))
    assert np.isnan(features.f60_n)


@pytest.mark.parametrize(
    ("angles", "forces", "fragment"),
    [
        ([0, 1, np.nan], [0, 1, 2], "NaN"),
        ([0, 2, 1], [0, 1, 2], "increasing"),
        ([0, 1], [0, 1, 2], "equal length"),
    ],
)
def test_bad_curves_are_refused(angles, forces, fragment):
    with pytest.raises(InputDataError, match=fragment):
        curve_features(np.array(angles, float), np.array(forces, float))
