"""Closed forms of the coated section: its elastic bending stiffness and plastic moment.

Plain arithmetic, kept out of :mod:`._coating` (whose return mapping numba compiles) so
that the model state, the calibration's coordinates and the CLI use them without
loading numba.
"""

from __future__ import annotations

__all__ = ["bending_stiffness", "plastic_moment"]


def bending_stiffness(ecoat_mpa: float, tcoat_mm: float, thickness_mm: float) -> float:
    """Elastic bending stiffness per unit width, ``D = 2/3·E·(z2³ − z1³)`` [N·mm]."""
    z2 = thickness_mm / 2.0
    z1 = z2 - tcoat_mm
    return 2.0 / 3.0 * ecoat_mpa * (z2**3 - z1**3)


def plastic_moment(scoat_mpa: float, tcoat_mm: float, thickness_mm: float) -> float:
    """Fully plastic moment per unit width, ``Mp = S·Tcoat·(t − Tcoat)`` [N·mm/mm]."""
    return scoat_mpa * tcoat_mm * (thickness_mm - tcoat_mm)
