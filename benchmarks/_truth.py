"""Checks of a calibration against the coating that made its data (a known truth)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def inside(value: float, combination: Mapping[str, Any] | None) -> bool | None:
    """``value`` within the stated 95 % interval of a combination (an entry of a
    determination's ``combinations``); None where no interval is stated: no
    determination (the calibration did not converge), or the curves do not determine
    the combination at all."""
    if combination is None or combination.get("low") is None:
        return None
    return combination["low"] <= value <= combination["high"]


def mark(covered: bool | None) -> str:
    """``y``/``n``/``-`` for a column of whether an interval holds the truth."""
    return "-" if covered is None else ("y" if covered else "n")
