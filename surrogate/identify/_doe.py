"""Designs of experiments over a parameter space (``scipy.stats.qmc``, seeded)."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pandas as pd
from scipy.stats import qmc

from .._errors import InputDataError
from ..study._space import COATING_PARAMETERS, DESIGNS, PAPER_SPACE, ParameterSpace

__all__ = ["DESIGNS", "PAPER_STAGE1_LEVELS", "make_design", "paper_stage1_design"]

MAX_POINTS = 100_000

PAPER_STAGE1_LEVELS = {
    "ecoat_gpa": (0.5, 1.0, 2.0, 4.0),
    "scoat_gpa": (0.05, 0.1, 0.2, 0.4),
    "tcoat_mm": (0.01, 0.025, 0.05, 0.1),
}
"""The paper's Table 1: four levels of each coating parameter, 64 cases."""


def paper_stage1_design() -> pd.DataFrame:
    """The paper's stage-1 full factorial: 64 cases with their CAE-IDs.

    The CAE-IDs number the cases ``S1-01`` … ``S1-64`` in factorial order
    (Ecoat slowest, Tcoat fastest); the paper's own run numbers are not
    published with the table.
    """
    rows = itertools.product(*(PAPER_STAGE1_LEVELS[name] for name in COATING_PARAMETERS))
    table = pd.DataFrame(list(rows), columns=list(COATING_PARAMETERS))
    table.insert(0, "case_id", [f"S1-{i + 1:02d}" for i in range(len(table))])
    return table


def make_design(
    kind: str, space: ParameterSpace = PAPER_SPACE, *, n: int = 16, seed: int | None = 0
) -> pd.DataFrame:
    """Points of a design, one row each, with a ``case_id`` column first.

    Parameters
    ----------
    kind : {"factorial", "lhs", "sobol", "paper"}
        ``factorial``: ``n`` levels per parameter (``n**d`` points, evenly spaced
        in the scaled space); ``lhs``/``sobol``: ``n`` points (scrambled,
        seeded); ``paper``: the paper's 64 Table-1 cases (``n`` is ignored).
    space : ParameterSpace
        Ranges and scaling.
    n : int
        Number of points (levels per parameter for ``factorial``).
    seed : int or None
        Seed of the random designs.
    """
    if kind not in DESIGNS:
        raise InputDataError(f"design must be one of {', '.join(DESIGNS)}, got {kind!r}")
    if kind == "paper":
        return paper_stage1_design()
    if not isinstance(n, int | np.integer) or n < 1:
        raise InputDataError(f"n must be a whole number ≥ 1, got {n!r}")
    d = len(space)
    if kind == "factorial":
        if n**d > MAX_POINTS:
            raise InputDataError(
                f"a factorial with {n} levels in {d} parameters has {n**d} "
                f"points (> {MAX_POINTS}); use fewer levels or lhs/sobol"
            )
        levels = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
        unit = np.array(list(itertools.product(levels, repeat=d)))
    elif kind == "lhs":
        unit = qmc.LatinHypercube(d=d, seed=seed).random(n)
    else:
        with warnings.catch_warnings():  # balance warning for n not a power of two
            warnings.simplefilter("ignore", UserWarning)
            unit = qmc.Sobol(d=d, scramble=True, seed=seed).random(n)
    table = pd.DataFrame(space.from_unit(unit), columns=list(space.names))
    table.insert(0, "case_id", [f"{kind}-{i + 1:03d}" for i in range(len(table))])
    return table
