"""Study folders the tests write: measurements and a study file."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pandas as pd


def write_study(folder: Path, table: pd.DataFrame, toml: str) -> Path:
    """``folder`` with the measurements as ``tests.csv`` and ``study.toml`` (``toml``
    dedented); the study file's path."""
    folder.mkdir(parents=True, exist_ok=True)
    table.to_csv(folder / "tests.csv", index=False)
    path = folder / "study.toml"
    path.write_text(textwrap.dedent(toml))
    return path
