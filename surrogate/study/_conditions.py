"""Test conditions: what a measured test records about how it was run.

``tension_n``, ``bending_length_mm``, ``free_length_mm`` (the test's strip
length from the clamp) and ``width_mm`` change the rig (the tension is the rig's
dead end load, not an effect); ``direction`` (warp or weft) and ``rate_deg_s``
are read by effects. One place for their checks.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from .._errors import InputDataError
from .._validate import check_positive, check_range
from ._rig import Rig

__all__ = [
    "CONDITIONS",
    "DIRECTIONS",
    "NUMERIC_CONDITIONS",
    "RIG_CONDITIONS",
    "check_conditions",
    "rig_for",
]

CONDITIONS = (
    "tension_n",
    "direction",
    "rate_deg_s",
    "bending_length_mm",
    "free_length_mm",
    "width_mm",
)
DIRECTIONS = ("warp", "weft")
NUMERIC_CONDITIONS = tuple(name for name in CONDITIONS if name != "direction")
"""The conditions that are numbers (each in the unit its name says)."""
RIG_CONDITIONS = ("tension_n", "bending_length_mm", "free_length_mm", "width_mm")
"""The conditions that are fields of the test's rig (the same names)."""


def check_conditions(
    conditions: Mapping[str, Any] | None, *, read_by_effects: Iterable[str] = ()
) -> dict[str, Any]:
    """Validated conditions; an unknown name or a bad value is an InputDataError.

    Besides the known conditions, a column that an enabled effect declares in
    its ``reads`` (e.g. a plug-in's ``temperature_c``) passes through as it is.
    """
    checked: dict[str, Any] = {}
    extra = set(read_by_effects) - set(CONDITIONS)
    for name, value in (conditions or {}).items():
        if name in extra:
            checked[name] = value
            continue
        if name not in CONDITIONS:
            raise InputDataError(
                f"unknown test condition {name!r}; known: {', '.join(CONDITIONS)} "
                "(or a column an enabled effect reads)"
            )
        if name == "direction":
            if value not in DIRECTIONS:
                raise InputDataError(f"direction must be warp or weft, got {value!r}")
            checked[name] = value
        elif name == "tension_n":
            checked[name] = check_range(name, value, 0.0, 1e5, unit="N")
        else:
            checked[name] = check_positive(name, value)
    return checked


def rig_for(rig: Rig, conditions: Mapping[str, Any]) -> Rig:
    """The rig of one test: the study's rig with that test's conditions."""
    changes = {name: conditions[name] for name in RIG_CONDITIONS if name in conditions}
    return rig.replace(**changes) if changes else rig
