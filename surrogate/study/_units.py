"""Units: the paper's GPa at the interfaces, MPa (N/mm²) inside. One place."""

from __future__ import annotations

__all__ = ["MPA_PER_GPA", "gpa_to_mpa", "mpa_to_gpa"]

MPA_PER_GPA = 1000.0


def gpa_to_mpa(value_gpa: float) -> float:
    return value_gpa * MPA_PER_GPA


def mpa_to_gpa(value_mpa: float) -> float:
    return value_mpa / MPA_PER_GPA
