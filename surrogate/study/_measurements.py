"""Measured curves: the long CSV format of design.md §5, validated.

``test_id, angle_deg, force_n`` plus optional condition columns
(``tension_n, direction, rate_deg_s, bending_length_mm, width_mm``); every
other column is kept as a covariate for the diagnosis. Conditions and
covariates are constant within a test. Tests with the same conditions are
replicates (a covariate such as the lab temperature may differ between them):
their scatter estimates the measurement noise.

The files may come as labs export them (another delimiter, a decimal comma, mN or
radians, one file per test with its conditions in a table or in its name):
:mod:`._lab_files` reads them into this format, N and degrees.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .._errors import InputDataError, InputDataWarning
from ._conditions import CONDITIONS, DIRECTIONS, NUMERIC_CONDITIONS
from ._formats import MeasurementFormat
from ._lab_files import SourceTable, numbers, read_sources

__all__ = ["MeasurementSet", "load_measurements"]

REQUIRED = ("test_id", "angle_deg", "force_n")
_UNITLESS = {
    "tension": "tension_n",
    "rate": "rate_deg_s",
    "bending_length": "bending_length_mm",
    "width": "width_mm",
    "angle": "angle_deg",
    "force": "force_n",
}


@dataclass(frozen=True)
class MeasurementSet:
    """Validated measured curves.

    Attributes
    ----------
    curves : DataFrame
        Long format, sorted by test then angle.
    tests : DataFrame
        One row per test: ``test_id``, its conditions and covariates.
    conditions : tuple of str
        Condition columns present.
    covariates : tuple of str
        Other columns (kept for the diagnosis).
    noise_n : float or None
        Noise estimated from replicates (pooled standard deviation), if any.
    """

    curves: pd.DataFrame
    tests: pd.DataFrame
    conditions: tuple[str, ...]
    covariates: tuple[str, ...]
    noise_n: float | None
    noise_dof: int = 0

    def curve(self, test_id: Any) -> tuple[np.ndarray, np.ndarray]:
        rows = self.curves[self.curves.test_id == test_id]
        return rows.angle_deg.to_numpy(float), rows.force_n.to_numpy(float)

    def conditions_of(self, test_id: Any) -> dict[str, Any]:
        row = self.tests[self.tests.test_id == test_id].iloc[0]
        return {
            name: (row[name] if name == "direction" else float(row[name]))
            for name in self.conditions
        }


def load_measurements(
    path: str | Path, *, file_format: MeasurementFormat | None = None
) -> MeasurementSet:
    """Read and validate a study's measurements; a bad file raises InputDataError (one line).

    Parameters
    ----------
    path : str or Path
        A measurement file, or a glob of them (``tests/*.csv``).
    file_format : MeasurementFormat, optional
        How the files are read (the ``[measurements]`` keys); default: delimiter and
        decimal mark detected, forces in N and angles in degrees unless a column's
        name says otherwise (:mod:`._lab_files`).
    """
    path = Path(path)
    sources, notes = read_sources(path, file_format or MeasurementFormat())
    if len(sources) == 1:
        data = measurements_from(sources[0].table, where=str(path))
    else:
        for source in sources:  # each file's errors name that file
            _check_values(source.table, str(source.path))
        _check_alike(sources)
        table = pd.concat([s.table for s in sources], ignore_index=True)
        data = measurements_from(table, where=str(path))
    for note in notes:  # odd but valid data
        warnings.warn(note, InputDataWarning, stacklevel=2)
    return data


def _check_values(table: pd.DataFrame, where: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Check a long table (its numeric columns made floats in place); its conditions and
    covariates."""
    _check_columns(table, where)
    for name in ("angle_deg", "force_n", *[c for c in NUMERIC_CONDITIONS if c in table]):
        table[name] = numbers(table[name], name, where)
    if (table.force_n < 0).any():
        line = int(np.argmax((table.force_n < 0).to_numpy())) + 2
        raise InputDataError(
            f"{where}: force_n must be ≥ 0 (the probe only pushes), got "
            f"{table.force_n.iloc[line - 2]:g} at line {line}"
        )
    if "direction" in table:
        odd = sorted(set(table.direction.astype(str)) - set(DIRECTIONS))
        if odd:
            raise InputDataError(f"{where}: direction must be warp or weft, got {odd[0]!r}")
    conditions = tuple(c for c in CONDITIONS if c in table)
    covariates = tuple(c for c in table.columns if c not in (*REQUIRED, *conditions))
    _check_tests(table, conditions + covariates, where)
    return conditions, covariates


def _check_alike(sources: list[SourceTable]) -> None:
    """Files of one study: the same columns, and each test in one file only."""
    first = sources[0]
    seen = {t: first.path for t in first.table.test_id.unique()}
    for source in sources[1:]:
        if set(source.table.columns) != set(first.table.columns):
            differ = sorted(set(source.table.columns) ^ set(first.table.columns))
            raise InputDataError(
                f"{source.path}: its columns differ from those of {first.path} ({differ[0]} is "
                "in one only); give every file the same columns"
            )
        for test_id in source.table.test_id.unique():
            if test_id in seen:
                raise InputDataError(
                    f"{source.path}: test {test_id!r} is also in {seen[test_id]}; give each test "
                    "its own test_id"
                )
            seen[test_id] = source.path


def measurements_from(table: pd.DataFrame, *, where: str = "measurements") -> MeasurementSet:
    """The validated set of a long table (``where`` names it in errors)."""
    conditions, covariates = _check_values(table, where)
    tests = table.groupby("test_id", sort=False).first().reset_index()
    tests = tests[["test_id", *conditions, *covariates]]
    return MeasurementSet(
        table.reset_index(drop=True),
        tests,
        conditions,
        covariates,
        *_replicate_noise(table, tests, conditions),
    )


def _check_columns(table: pd.DataFrame, where: str) -> None:
    if table.empty:
        raise InputDataError(f"{where}: no rows")
    for column in table.columns:
        if column in _UNITLESS:
            raise InputDataError(
                f"{where}: column {column!r} has no unit; name it {_UNITLESS[column]!r}"
            )
    missing = [c for c in REQUIRED if c not in table.columns]
    if missing:
        raise InputDataError(
            f"{where}: missing column(s) {', '.join(missing)}; the format is "
            "test_id, angle_deg, force_n[, conditions…] (its columns: "
            f"{', '.join(map(str, table.columns))}): name yours with [measurements] columns"
        )


def _check_tests(table: pd.DataFrame, constant: tuple[str, ...], where: str) -> None:
    for test_id, rows in table.groupby("test_id", sort=False):
        angles = rows.angle_deg.to_numpy()
        if len(angles) < 3:
            raise InputDataError(
                f"{where}: test {test_id!r} has {len(angles)} points; a curve needs at least 3"
            )
        if len(np.unique(angles)) != len(angles):
            raise InputDataError(
                f"{where}: test {test_id!r} has duplicate angles; keep one point per angle"
            )
        if np.any(np.diff(angles) < 0):
            raise InputDataError(
                f"{where}: test {test_id!r} has unsorted angles; sort the "
                "rows of each test by angle_deg"
            )
        for column in constant:
            if rows[column].nunique(dropna=False) > 1:
                raise InputDataError(
                    f"{where}: {column} changes within test {test_id!r}; a test has one "
                    "value of each condition and covariate (a channel such as time is not "
                    "one: read only your columns with [measurements] columns)"
                )


def _replicate_noise(
    table: pd.DataFrame, tests: pd.DataFrame, keys: tuple[str, ...]
) -> tuple[float | None, int]:
    """Pooled standard deviation of replicates at common angles (or None), and its
    degrees of freedom."""
    groups = tests.groupby(list(keys), dropna=False).test_id if keys else [(None, tests.test_id)]
    squares, dof = 0.0, 0
    for _, ids in groups:
        if len(ids) < 2:
            continue
        curves = [table[table.test_id == t] for t in ids]
        low = max(c.angle_deg.min() for c in curves)
        high = min(c.angle_deg.max() for c in curves)
        # the first test's own angles: no smoothing where replicates share angles
        first = curves[0].angle_deg.to_numpy()
        grid = first[(first >= low) & (first <= high) & (first > 0.0)]
        if grid.size < 3:
            continue
        forces = np.array([np.interp(grid, c.angle_deg, c.force_n) for c in curves])
        squares += float(np.sum((forces - forces.mean(axis=0)) ** 2))
        dof += grid.size * (len(ids) - 1)
    return (float(np.sqrt(squares / dof)) if dof else None), dof
