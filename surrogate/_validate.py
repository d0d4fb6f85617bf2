"""Validation of user-supplied numbers: one place for the wording of errors."""

from __future__ import annotations

import math
import operator

from ._errors import InputDataError

__all__ = ["check_budget", "check_finite", "check_positive", "check_range", "check_seed"]


def check_finite(name: str, value: object) -> float:
    """``value`` as a float, or an :class:`InputDataError` naming ``name``."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputDataError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise InputDataError(f"{name} must be a finite number, got {value!r}")
    return number


def check_seed(seed: object) -> int:
    """``--seed``: a whole number ≥ 0 (what NumPy's and SciPy's generators take; a
    NumPy integer too)."""
    try:
        value = operator.index(seed)  # type: ignore[arg-type]
    except TypeError:
        value = -1
    if isinstance(seed, bool) or value < 0:
        raise InputDataError(f"--seed must be a whole number ≥ 0, got {seed!r}")
    return value


def check_budget(budget: object) -> None:
    """``--budget``: None (the study's) or a whole number ≥ 1 of solver runs. How many a
    job needs is its loop's, checked once the study is read."""
    if budget is None:
        return
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise InputDataError(f"--budget must be a whole number ≥ 1 of solver runs, got {budget!r}")


def check_positive(name: str, value: object, *, unit: str = "") -> float:
    """A finite number > 0."""
    number = check_finite(name, value)
    if number <= 0.0:
        raise InputDataError(f"{name} must be > 0{_unit(unit)}, got {number:g}")
    return number


def check_range(
    name: str,
    value: object,
    low: float,
    high: float,
    *,
    unit: str = "",
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """A finite number within ``[low, high]`` (ends open as asked)."""
    number = check_finite(name, value)
    too_low = number <= low if low_open else number < low
    too_high = number >= high if high_open else number > high
    if too_low or too_high:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        raise InputDataError(
            f"{name} must be in {left}{low:g}, {high:g}{right}{_unit(unit)}, got {number:g}"
        )
    return number


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""
