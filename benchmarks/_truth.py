"""Checks of a calibration against the coating that made its data (a known truth)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def inside(value: float, combination: Mapping[str, Any] | None) -> bool | None:
    """``value`` within the stated 95 % interval of a combination (an entry of a
    determination's ``combinations``; a one-sided bound's open side is null and holds
    everything on its side); None where no interval is stated: no determination (the
    calibration did not converge), or the curves bound the combination from neither
    side."""
    if combination is None:
        return None
    low, high = combination.get("low"), combination.get("high")
    if low is None and high is None:
        return None
    return (low is None or low <= value) and (high is None or value <= high)


def mark(covered: bool | None) -> str:
    """``y``/``n``/``-`` for a column of whether an interval holds the truth."""
    return "-" if covered is None else ("y" if covered else "n")
