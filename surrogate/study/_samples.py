"""Sample sets: one row per full-solver run, the curves alongside.

Files (all CSV/JSON, written atomically, never pickled):

- ``NAME.csv``: ``run_id, case_id, <parameters…>, f60_n, theta_sat_deg,
  saturated, status, reason, input_hash`` — status is ``ok`` or ``failed``
  (a failed run keeps its row and the solver's reason);
- ``NAME_curves.csv``: long format ``run_id, angle_deg, force_n, force_perp_n``;
- ``NAME.json``: provenance — solver, rig, parameter space, design, seed.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .._errors import InputDataError
from .._io import atomic_write_text
from ._space import PAPER_SPACE, ParameterSpace, ParameterSpec

__all__ = ["OUTPUT_COLUMNS", "SampleSet", "curves_path", "meta_path", "read_points"]

OUTPUT_COLUMNS = ("f60_n", "theta_sat_deg", "saturated", "status", "reason", "input_hash")
ID_COLUMNS = ("run_id", "case_id")
CURVE_COLUMNS = ("run_id", "angle_deg", "force_n", "force_perp_n")
FORMAT = "webbing-surrogate/samples"


def curves_path(path: Path) -> Path:
    return path.with_name(f"{path.stem}_curves.csv")


def meta_path(path: Path) -> Path:
    return path.with_suffix(".json")


@dataclass(frozen=True)
class SampleSet:
    """Runs of a full solver over a design.

    Attributes
    ----------
    runs : DataFrame
        One row per run (columns: see the module docstring).
    curves : DataFrame
        Long format curves of the successful runs.
    space : ParameterSpace
        The parameters varied (columns of ``runs`` between the ids and outputs).
    meta : dict
        Provenance (solver, rig, design, seed).
    """

    runs: pd.DataFrame
    curves: pd.DataFrame
    space: ParameterSpace
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> pd.DataFrame:
        """The successful runs."""
        return self.runs[self.runs["status"] == "ok"]

    @property
    def n_failed(self) -> int:
        return int((self.runs["status"] != "ok").sum())

    def curve_matrix(self, run_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Angles (m,) and forces (n, m) of the successful runs, in ``run_ids`` order."""
        ids = self.ok["run_id"].to_numpy() if run_ids is None else run_ids
        wide = self.curves.pivot(index="run_id", columns="angle_deg", values="force_n")
        wide = wide.loc[ids]
        return wide.columns.to_numpy(dtype=float), wide.to_numpy(dtype=float)

    def write(self, path: str | Path) -> Path:
        """Write the three files; each one atomically, the run table last."""
        path = Path(path)
        buffer = io.StringIO()
        self.curves.to_csv(buffer, index=False, float_format="%.6g")
        atomic_write_text(curves_path(path), buffer.getvalue())
        meta = {"format": FORMAT, "version": 1, "space": self.space.to_dict(), **self.meta}
        atomic_write_text(meta_path(path), json.dumps(meta, indent=2) + "\n")
        buffer = io.StringIO()
        self.runs.to_csv(buffer, index=False, float_format="%.10g")
        atomic_write_text(path, buffer.getvalue())
        return path

    @classmethod
    def read(cls, path: str | Path) -> SampleSet:
        """Read and validate a sample set; a bad file raises :class:`InputDataError`."""
        path = Path(path)
        runs = _read_csv(path, "sample file")
        _require(runs, ("run_id", "status", "f60_n", "theta_sat_deg"), path)
        meta: dict[str, Any] = {}
        if meta_path(path).exists():
            try:
                meta = json.loads(meta_path(path).read_text(encoding="utf-8"))
            except json.JSONDecodeError as error:
                raise InputDataError(
                    f"{meta_path(path)}: not valid JSON ({error.msg} at line "
                    f"{error.lineno}); delete it or restore it"
                ) from None
        names = [c for c in runs.columns if c not in (*ID_COLUMNS, *OUTPUT_COLUMNS)]
        if not names:
            raise InputDataError(f"{path}: no parameter columns (e.g. ecoat_gpa) found")
        space = _space_from(meta, names, runs, path)
        _validate_runs(runs, names, path)
        curve_file = curves_path(path)
        curves = (
            _read_csv(curve_file, "curve file")
            if curve_file.exists()
            else pd.DataFrame(columns=list(CURVE_COLUMNS))
        )
        meta = {k: v for k, v in meta.items() if k not in ("format", "version", "space")}
        return cls(runs, curves, space, meta)


def read_points(path: str | Path, names: tuple[str, ...]) -> pd.DataFrame:
    """A CSV of points with at least the columns ``names``, validated."""
    path = Path(path)
    table = _read_csv(path, "points file")
    _require(table, names, path)
    _check_numeric(table, names, path)
    return table


def _read_csv(path: Path, what: str) -> pd.DataFrame:
    if not path.exists():
        raise InputDataError(f"{what} {path} does not exist; check the path")
    try:
        table = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else "unreadable"
        raise InputDataError(f"{what} {path} is not a readable CSV ({reason})") from None
    if table.empty:
        raise InputDataError(f"{what} {path} has no rows")
    return table


def _require(table: pd.DataFrame, columns: tuple[str, ...], path: Path) -> None:
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise InputDataError(
            f"{path}: missing column(s) {', '.join(missing)}; "
            f"found {', '.join(map(str, table.columns))}"
        )


def _check_numeric(table: pd.DataFrame, names: tuple[str, ...] | list[str], path: Path) -> None:
    for name in names:
        values = pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad)) + 2  # 1-based, after the header line
            raise InputDataError(
                f"{path}: column {name} has a missing, NaN or non-numeric "
                f"value at line {row} ({str(table[name].iloc[row - 2])!r}); fix it"
            )
        if name.endswith(("_gpa", "_mm")) and np.any(values <= 0.0):
            row = int(np.argmax(values <= 0.0)) + 2
            raise InputDataError(
                f"{path}: column {name} must be > 0, got {values[row - 2]:g} at line {row}"
            )


def _validate_runs(runs: pd.DataFrame, names: list[str], path: Path) -> None:
    _check_numeric(runs, names, path)
    statuses = set(runs["status"].astype(str))
    if not statuses <= {"ok", "failed"}:
        raise InputDataError(
            f"{path}: status must be ok or failed, got {sorted(statuses - {'ok', 'failed'})}"
        )
    ok = runs[runs["status"] == "ok"]
    _check_numeric(ok, ["f60_n", "theta_sat_deg"], path)
    if runs["run_id"].duplicated().any():
        raise InputDataError(f"{path}: run_id values must be unique")


def _space_from(
    meta: dict[str, Any], names: list[str], runs: pd.DataFrame, path: Path
) -> ParameterSpace:
    declared = {item["name"]: item for item in meta.get("space", [])}
    specs = []
    for name in names:
        if name in declared:
            specs.append(ParameterSpec(**declared[name]))
        elif name in PAPER_SPACE.names:
            specs.append(PAPER_SPACE[name])
        else:
            values = pd.to_numeric(runs[name], errors="coerce")
            low, high = float(values.min()), float(values.max())
            if not (np.isfinite(low) and np.isfinite(high)) or low == high:
                raise InputDataError(
                    f"{path}: cannot infer the range of column {name}; give it in the .json sidecar"
                )
            specs.append(ParameterSpec(name, low, high, log=bool(low > 0 and high / low > 10)))
    return ParameterSpace(tuple(specs))
