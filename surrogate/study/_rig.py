"""The 2-point bending rig: geometry, friction, end load, discretisation."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from .._errors import InputDataError
from .._validate import check_positive, check_range

__all__ = ["Rig"]


@dataclass(frozen=True)
class Rig:
    """The test rig, validated on construction (defaults: design.md §3).

    Parameters
    ----------
    thickness_mm : float
        Webbing thickness ``t``.
    width_mm : float
        Specimen width ``b``; forces are for the full width.
    bending_length_mm : float
        Horizontal distance ``l`` from the rotation axis to the probe centre.
    probe_radius_mm : float
        Radius ``r`` of the rigid probe; the mid-line keeps ``r + t/2`` from its centre.
    free_length_mm : float
        Free strip length from the clamp edge.
    friction : float
        Coulomb coefficient at the probe.
    max_angle_deg : float
        The fixture rotates 0 → ``max_angle_deg``, output every 1°.
    element_size_mm : float or None
        ``None``: the default graded mesh (``l/25`` over the loaded zone);
        a number: a uniform mesh of that size (e.g. 2.5 mm, as in an LS-DYNA
        system model) to see what a coarse mesh does to the curve.
    tension_n : float
        Dead load at the free end along the undeformed strip, away from the clamp.
    """

    thickness_mm: float = 1.2
    width_mm: float = 38.0
    bending_length_mm: float = 10.0
    probe_radius_mm: float = 1.0
    free_length_mm: float = 35.0
    friction: float = 0.1
    max_angle_deg: float = 90.0
    element_size_mm: float | None = None
    tension_n: float = 0.0

    def __post_init__(self) -> None:
        checked = {
            "thickness_mm": check_positive("thickness_mm", self.thickness_mm, unit="mm"),
            "width_mm": check_positive("width_mm", self.width_mm, unit="mm"),
            "bending_length_mm": check_positive(
                "bending_length_mm", self.bending_length_mm, unit="mm"
            ),
            "probe_radius_mm": check_range(
                "probe_radius_mm",
                self.probe_radius_mm,
                0.0,
                10.0 * self.bending_length_mm,
                unit="mm",
            ),
            "free_length_mm": check_positive("free_length_mm", self.free_length_mm, unit="mm"),
            "friction": check_range("friction", self.friction, 0.0, 2.0),
            "max_angle_deg": check_range(
                "max_angle_deg", self.max_angle_deg, 0.0, 90.0, unit="deg", low_open=True
            ),
            "tension_n": check_range("tension_n", self.tension_n, 0.0, 1e5, unit="N"),
        }
        if self.element_size_mm is not None:
            checked["element_size_mm"] = check_range(
                "element_size_mm",
                self.element_size_mm,
                0.0,
                self.bending_length_mm,
                unit="mm",
                low_open=True,
            )
        for name, value in checked.items():
            object.__setattr__(self, name, value)
        needed = 2.0 * self.bending_length_mm
        if self.free_length_mm < needed:
            raise InputDataError(
                f"free_length_mm must be ≥ 2 × bending_length_mm = {needed:g} mm so the strip "
                f"stays on the probe up to 90°, got {self.free_length_mm:g}: set [rig] "
                f"free_length_mm in the study file (simulate: --free-length), or give each test "
                f"its strip length in a free_length_mm column of the measurements"
            )

    @property
    def contact_radius_mm(self) -> float:
        """Distance kept between the mid-line and the probe centre, ``r + t/2``."""
        return self.probe_radius_mm + 0.5 * self.thickness_mm

    def replace(self, **changes: Any) -> Rig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
