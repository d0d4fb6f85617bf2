"""Measurement files: the long format, validated; replicates estimate the noise."""

import numpy as np
import pandas as pd
import pytest

from surrogate import InputDataError
from surrogate.study._measurements import load_measurements


def _table(noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for test_id, direction, tension in (
        ("a1", "warp", 0.0),
        ("a2", "warp", 0.0),
        ("b1", "weft", 10.0),
    ):
        for angle in range(0, 91, 5):
            rows.append(
                {
                    "test_id": test_id,
                    "angle_deg": float(angle),
                    "force_n": 0.15 * angle + noise * rng.standard_normal(),
                    "direction": direction,
                    "tension_n": tension,
                    "temperature_c": 23.0,
                }
            )
    table = pd.DataFrame(rows)
    table["force_n"] = table.force_n.clip(lower=0.0)
    return table


def test_good_file_with_conditions_covariates_and_replicates(tmp_path):
    _table(noise=0.05).to_csv(tmp_path / "m.csv", index=False)
    data = load_measurements(tmp_path / "m.csv")
    assert list(data.tests.test_id) == ["a1", "a2", "b1"]
    assert data.conditions == ("tension_n", "direction")
    assert data.covariates == ("temperature_c",)
    assert data.conditions_of("b1") == {"tension_n": 10.0, "direction": "weft"}
    # a1 and a2 are replicates; pooled sd of two curves ≈ the noise (seeded)
    assert data.noise_n == pytest.approx(0.05, rel=0.35)


def test_no_replicates_no_noise_estimate(tmp_path):
    _table().query("test_id != 'a2'").to_csv(tmp_path / "m.csv", index=False)
    assert load_measurements(tmp_path / "m.csv").noise_n is None


BAD = {
    "missing-column": (lambda t: t.drop(columns=["force_n"]), "missing column(s) force_n"),
    "nan": (lambda t: t.assign(force_n=[np.nan, *t.force_n[1:]]), "NaN"),
    "inf": (lambda t: t.assign(angle_deg=[np.inf, *t.angle_deg[1:]]), "inf"),
    "negative": (lambda t: t.assign(force_n=[-1.0, *t.force_n[1:]]), "force_n must be ≥ 0"),
    "duplicate": (lambda t: t.assign(angle_deg=[5.0, *t.angle_deg[1:]]), "duplicate angles"),
    "unsorted": (
        lambda t: t.assign(angle_deg=[10.0, 5.0, 0.0, *t.angle_deg[3:]]),
        "unsorted angles",
    ),
    "unitless": (
        lambda t: t.rename(columns={"tension_n": "tension"}),
        "column 'tension' has no unit; name it 'tension_n'",
    ),
    "direction": (
        lambda t: t.assign(direction=["diagonal", *t.direction[1:]]),
        "direction must be warp or weft",
    ),
    "changing-condition": (
        lambda t: t.assign(tension_n=[5.0, *t.tension_n[1:]]),
        "tension_n changes within test",
    ),
    "text-force": (lambda t: t.assign(force_n=["abc", *t.force_n[1:]]), "non-numeric"),
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_measurement_files_are_refused(tmp_path, kind):
    change, fragment = BAD[kind]
    change(_table()).to_csv(tmp_path / "m.csv", index=False)
    with pytest.raises(InputDataError) as caught:
        load_measurements(tmp_path / "m.csv")
    assert fragment in str(caught.value) and "\n" not in str(caught.value)


def test_empty_and_garbage_files(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "header.csv").write_text("test_id,angle_deg,force_n\n")
    for name in ("empty.csv", "header.csv", "absent.csv"):
        with pytest.raises(InputDataError):
            load_measurements(tmp_path / name)


def test_a_test_at_a_longer_bending_length_brings_its_strip_length(tmp_path):
    """The specimen length is a property of the test: a free_length_mm column."""
    from surrogate import Rig
    from surrogate.study import rig_for

    with pytest.raises(InputDataError, match=r"got 35: set \[rig\] free_length_mm in the study"):
        rig_for(Rig(), {"bending_length_mm": 20.0})
    assert rig_for(Rig(), {"bending_length_mm": 20.0, "free_length_mm": 45.0}).free_length_mm == 45
    table = _table()
    table["bending_length_mm"] = 20.0
    table["free_length_mm"] = 45.0
    table.to_csv(tmp_path / "m.csv", index=False)
    data = load_measurements(tmp_path / "m.csv")
    assert "free_length_mm" in data.conditions and "free_length_mm" not in data.covariates


def test_a_long_csv_reads_as_it_always_did(tmp_path):
    """Before lab formats, a file was ``pd.read_csv`` then ``measurements_from``: the same set,
    exactly, for the shipped file and this module's files."""
    from surrogate.study._measurements import measurements_from
    from tests.conftest import REPO

    _table(noise=0.05).to_csv(tmp_path / "m.csv", index=False)
    for path in (REPO / "data" / "measurements" / "webbing_tests.csv", tmp_path / "m.csv"):
        before, now = measurements_from(pd.read_csv(path), where=str(path)), load_measurements(path)
        pd.testing.assert_frame_equal(now.curves, before.curves, check_exact=True)
        pd.testing.assert_frame_equal(now.tests, before.tests, check_exact=True)
        assert (now.conditions, now.covariates) == (before.conditions, before.covariates)
        assert (now.noise_n, now.noise_dof) == (before.noise_n, before.noise_dof)
