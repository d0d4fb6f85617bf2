"""Units: one place for every unit the product reads.

- stresses: the paper's GPa at the interfaces, MPa (N/mm²) inside;
- measured forces and angles: a lab's file may be in any of :data:`FORCE_UNITS`
  and :data:`ANGLE_UNITS`; they are converted once, on load, into N and degrees.

A column's name may say its unit: the product's own ``force_mn`` / ``angle_rad``
(``<quantity>_<unit>``, lower case) or a lab's ``Force [mN]`` / ``Angle (rad)``
(the unit in brackets, as written). :func:`unit_in_name` reads it.
"""

from __future__ import annotations

import math
import re
from typing import TypeVar

import numpy as np

from .._errors import InputDataError

__all__ = [
    "ANGLE_UNITS",
    "FORCE_UNITS",
    "MPA_PER_GPA",
    "check_unit",
    "gpa_to_mpa",
    "mpa_to_gpa",
    "to_degrees",
    "to_newtons",
    "unit_in_name",
]

MPA_PER_GPA = 1000.0

STANDARD_GRAVITY_M_S2 = 9.80665
"""g₀ (CGPM 1901): 1 gf = 9.80665 mN, 1 kgf = 9.80665 N."""

FORCE_UNITS = {
    "N": 1.0,
    "mN": 1e-3,
    "kN": 1e3,
    "gf": STANDARD_GRAVITY_M_S2 * 1e-3,
    "kgf": STANDARD_GRAVITY_M_S2,
    "lbf": 0.45359237 * STANDARD_GRAVITY_M_S2,  # the international avoirdupois pound
}
"""Newtons per unit of each force unit a measurement file may use."""

ANGLE_UNITS = {"deg": 1.0, "rad": 180.0 / math.pi}
"""Degrees per unit of each angle unit a measurement file may use."""

Values = TypeVar("Values", float, np.ndarray)  # a value or an array of them

_UNITS = {"force": FORCE_UNITS, "angle": ANGLE_UNITS}
_ALIASES = {"°": "deg"}  # "Angle [°]", as testers' software writes it
_BRACKETS = re.compile(r"[\[(]\s*([^\[\]()]+?)\s*[\])]")


def gpa_to_mpa(value_gpa: float) -> float:
    return value_gpa * MPA_PER_GPA


def mpa_to_gpa(value_mpa: float) -> float:
    return value_mpa / MPA_PER_GPA


def check_unit(key: str, unit: object, quantity: str) -> str:
    """``unit`` if it is a known unit of ``quantity`` ("force" or "angle"), else an
    InputDataError naming ``key`` and the known units."""
    units = _UNITS[quantity]
    if not isinstance(unit, str) or unit not in units:
        raise InputDataError(f"{key} must be one of {', '.join(units)}, got {unit!r}")
    return unit


def to_newtons(force: Values, unit: str) -> Values:
    """Forces in ``unit`` (a key of :data:`FORCE_UNITS`) → N."""
    return force * FORCE_UNITS[unit]


def to_degrees(angle: Values, unit: str) -> Values:
    """Angles in ``unit`` (a key of :data:`ANGLE_UNITS`) → degrees."""
    return angle * ANGLE_UNITS[unit]


def unit_in_name(column: str, quantity: str) -> str | None:
    """The unit a column's name states for ``quantity``, or None if it states none.

    ``force_mn`` → ``"mN"`` (the product's ``<quantity>_<unit>``, lower case);
    ``Force [mN]`` or ``Kraft (mN)`` → ``"mN"`` (the last bracketed word, case as
    written: ``[MN]`` is not mN). A bracketed unit that is not one of the known units
    of ``quantity`` is an InputDataError: the column would otherwise be read in the
    wrong unit.
    """
    units = _UNITS[quantity]
    prefix = f"{quantity}_"
    if column.lower().startswith(prefix):
        suffix = column[len(prefix) :].lower()
        return next((unit for unit in units if unit.lower() == suffix), None)
    found = _BRACKETS.findall(column)
    if not found:
        return None
    unit = _ALIASES.get(found[-1], found[-1])
    if unit not in units:
        raise InputDataError(
            f"column {column!r} is in {found[-1]!r}, which is not a {quantity} unit this "
            f"product reads ({', '.join(units)}); convert the column"
        )
    return unit
