"""Study folders the tests write: measurements and a study file."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pandas as pd

RANGES = """
[parameters]
ecoat_gpa = { low = 0.5,  high = 4.0, log = true }
scoat_gpa = { low = 0.05, high = 0.4, log = true }
tcoat_mm  = { low = 0.01, high = 0.1, log = true }
"""  # the coating ranges the calibration and diagnosis tests search


def write_study(folder: Path, table: pd.DataFrame, toml: str, *, ranges: bool = False) -> Path:
    """``folder`` with the measurements as ``tests.csv`` and ``study.toml`` (``toml``
    dedented, and ``RANGES`` where asked); the study file's path."""
    folder.mkdir(parents=True, exist_ok=True)
    table.to_csv(folder / "tests.csv", index=False)
    path = folder / "study.toml"
    path.write_text(textwrap.dedent(toml) + (RANGES if ranges else ""))
    return path
