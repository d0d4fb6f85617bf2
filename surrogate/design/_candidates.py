"""Candidate tests inside the study's ``[design]``: the conditions a lab can set.

A full factorial of ``LEVELS`` values of each numeric range (its ends and points between,
log-spaced where declared) and every choice of a categorical condition, thinned to at
most ``MOST`` by a scrambled Sobol choice where it is larger; every condition the
section leaves out keeps the reference test's value (the measurements' first test).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.stats import qmc

from ..study._design import DesignSpec

__all__ = ["LEVELS", "MOST", "candidate_tests"]

LEVELS = 4  # values of each numeric range: its ends and two between
MOST = 64  # candidate tests at most


def candidate_tests(
    design: DesignSpec, reference: Mapping[str, Any], *, seed: int = 0
) -> list[dict[str, Any]]:
    """The candidate tests' conditions (each a mapping like a measured test's), the
    reference test's where ``design`` does not vary them."""
    axes: list[list[tuple[str, Any]]] = [
        [(r.name, round(r.at(k / (LEVELS - 1)), 6)) for k in range(LEVELS)] for r in design.ranges
    ]
    axes += [[(name, choice) for choice in choices] for name, choices in design.choices.items()]
    grid = [dict(combination) for combination in itertools.product(*axes)]
    if len(grid) > MOST:
        picks = qmc.Sobol(1, scramble=True, seed=seed).random_base2(7)[:, 0]
        chosen = sorted({int(p * len(grid)) for p in picks})[:MOST]
        grid = [grid[k] for k in chosen]
    return [{**dict(reference), **conditions} for conditions in grid]


def as_json(conditions: Mapping[str, Any]) -> dict[str, Any]:
    """Conditions with plain JSON values."""
    return {k: (v if isinstance(v, str) else float(np.asarray(v))) for k, v in conditions.items()}
