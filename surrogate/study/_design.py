"""``[design]``: what the lab can vary for its next test, and its limits.

Each key but ``replicates`` is a per-test condition (:data:`~._conditions.CONDITIONS`:
``tension_n``, ``bending_length_mm``, ``rate_deg_s``, …) with its range —
``{ low = 5.0, high = 17.5 }``, optionally ``log = true`` — or, for ``direction``, the
list of directions the lab can cut (``["warp", "weft"]``). ``replicates`` is how many
specimens a test gets (default 2). A condition the section leaves out is held at the
reference test's value (the first test of the measurements). Validated like every
section: a bad key or value is one line naming it and the fix.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .._errors import InputDataError
from ._conditions import CONDITIONS, DIRECTIONS
from ._keys import keys

__all__ = ["DesignRange", "DesignSpec", "conditions_text", "design_settings"]

DEFAULT_REPLICATES = 2


@dataclass(frozen=True)
class DesignRange:
    """A numeric condition the lab can set within ``low``–``high`` (``log``: spaced on a
    log scale, as a rate is)."""

    name: str
    low: float
    high: float
    log: bool = False

    def at(self, share: float) -> float:
        """The value a share (0–1) of the way through the range."""
        if self.log:
            return math.exp(math.log(self.low) + share * math.log(self.high / self.low))
        return self.low + share * (self.high - self.low)


@dataclass(frozen=True)
class DesignSpec:
    """The validated ``[design]`` section: numeric ``ranges``, ``choices`` of a
    categorical condition (``direction``), ``replicates`` per test. Empty: the section is
    absent (``surrogate next-test`` then refuses, naming the section to add)."""

    ranges: tuple[DesignRange, ...] = ()
    choices: dict[str, tuple[str, ...]] = field(default_factory=dict)
    replicates: int = DEFAULT_REPLICATES

    @property
    def empty(self) -> bool:
        return not self.ranges and not self.choices

    @property
    def conditions(self) -> tuple[str, ...]:
        """The conditions the lab can vary, in the order of :data:`CONDITIONS`."""
        named = {r.name for r in self.ranges} | set(self.choices)
        return tuple(c for c in CONDITIONS if c in named)


def design_settings(section: dict[str, Any], where: str) -> DesignSpec:
    """``[design]`` of study file ``where``, or a one-line error naming key, value and fix."""
    ranges, choices = [], {}
    replicates = DEFAULT_REPLICATES
    for key, value in section.items():
        if key == "replicates":
            replicates = _replicates(value, where)
        elif key == "direction":
            choices[key] = _directions(value, where)
        elif key in keys("design"):
            ranges.append(_range(key, value, where))
        else:
            raise InputDataError(
                f"{where}: unknown key in [design] {key!r}; allowed: "
                f"{', '.join(keys('design'))} (the conditions a lab can vary)"
            )
    return DesignSpec(tuple(ranges), choices, replicates)


def _replicates(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 20:
        raise InputDataError(
            f"{where}: design.replicates must be a whole number of specimens 1–20, got {value!r}"
        )
    return value


def _directions(value: Any, where: str) -> tuple[str, ...]:
    if (
        not isinstance(value, list)
        or not value
        or any(v not in DIRECTIONS for v in value)
        or len(set(value)) != len(value)
    ):
        raise InputDataError(
            f"{where}: design.direction must be a list of distinct directions of {DIRECTIONS} "
            f'such as ["warp", "weft"], got {value!r}'
        )
    return tuple(value)


def _range(name: str, value: Any, where: str) -> DesignRange:
    """``{ low, high, log }`` of a numeric condition: finite, low ≤ high, log > 0; a
    tension may be 0, every other condition is positive."""
    example = f"{name} = {{ low = 5.0, high = 17.5 }}"
    if (
        not isinstance(value, dict)
        or set(value) - {"low", "high", "log"}
        or not ({"low", "high"} <= set(value))
    ):
        raise InputDataError(
            f"{where}: design.{name} must be a table with low and high (optional log), "
            f"e.g. {example}; got {value!r}"
        )
    low, high, log = value["low"], value["high"], value.get("log", False)
    numbers = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (low, high))
    if not numbers or not all(math.isfinite(float(v)) for v in (low, high)):
        raise InputDataError(f"{where}: design.{name} low and high must be numbers, got {value!r}")
    if not isinstance(log, bool):
        raise InputDataError(f"{where}: design.{name}.log must be true or false, got {log!r}")
    floor = 0.0 if name == "tension_n" else math.nextafter(0.0, 1.0)
    if not floor <= low <= high:
        bound = "≥ 0" if name == "tension_n" else "> 0"
        raise InputDataError(
            f"{where}: design.{name} needs {bound} and low ≤ high, got low = {low!r}, "
            f"high = {high!r}"
        )
    if log and low <= 0:
        raise InputDataError(f"{where}: design.{name} is log-spaced, so low must be > 0")
    return DesignRange(name, float(low), float(high), bool(log))


def conditions_text(conditions: Mapping[str, Any], varied: tuple[str, ...] | None = None) -> str:
    """The conditions a test sets, as tables and messages show them ("bending_length_mm 5,
    tension_n 60"): those of ``varied`` (default: all of them)."""
    varied = tuple(conditions) if varied is None else varied
    return (
        ", ".join(
            f"{name} {conditions[name]:g}"
            if not isinstance(conditions[name], str)
            else f"{name} {conditions[name]}"
            for name in varied
            if name in conditions
        )
        or "the reference test's conditions"
    )
