"""Designs of experiments."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import qmc

import surrogate
from surrogate import PAPER_SPACE, InputDataError, make_design, paper_stage1_design

DATA = Path(__file__).resolve().parents[1] / "data"


def test_paper_design_is_table_1_and_matches_the_shipped_file():
    design = paper_stage1_design()
    assert len(design) == 64 and design.case_id.is_unique
    assert sorted(design.ecoat_gpa.unique()) == [0.5, 1.0, 2.0, 4.0]
    assert sorted(design.scoat_gpa.unique()) == [0.05, 0.1, 0.2, 0.4]
    assert sorted(design.tcoat_mm.unique()) == [0.01, 0.025, 0.05, 0.1]
    assert len(design.drop_duplicates(["ecoat_gpa", "scoat_gpa", "tcoat_mm"])) == 64
    shipped = pd.read_csv(DATA / "paper_stage1_design.csv")
    pd.testing.assert_frame_equal(shipped, design)


@pytest.mark.parametrize("kind", ["lhs", "sobol"])
def test_random_designs_are_seeded_scipy_qmc_in_log_space(kind):
    a = make_design(kind, n=16, seed=3)
    b = make_design(kind, n=16, seed=3)
    c = make_design(kind, n=16, seed=4)
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a.ecoat_gpa, c.ecoat_gpa)
    unit = PAPER_SPACE.to_unit(a[list(PAPER_SPACE.names)].to_numpy())
    engine = (
        qmc.LatinHypercube(d=3, seed=3) if kind == "lhs" else qmc.Sobol(d=3, scramble=True, seed=3)
    )
    np.testing.assert_allclose(unit, engine.random(16), atol=1e-12)
    if kind == "lhs":  # one point per stratum in every dimension
        for column in unit.T:
            assert sorted(np.floor(column * 16).astype(int)) == list(range(16))


def test_factorial_levels():
    design = make_design("factorial", n=3)
    assert len(design) == 27
    np.testing.assert_allclose(sorted(design.ecoat_gpa.unique()), [0.5, np.sqrt(2.0), 4.0])


@pytest.mark.parametrize(("kind", "n"), [("lhs", 0), ("bogus", 4), ("factorial", 100)])
def test_bad_design_requests(kind, n):
    with pytest.raises(InputDataError):
        make_design(kind, n=n)


def test_doe_without_run_writes_points(tmp_path):
    result = surrogate.doe("sobol", n=8, seed=1, out=tmp_path / "points.csv")
    assert result.n_points == 8 and not result.ran
    table = pd.read_csv(tmp_path / "points.csv")
    assert list(table.columns) == ["case_id", *PAPER_SPACE.names]
