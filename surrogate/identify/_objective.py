"""The misfit and the constraint rules of the main job: one place for each definition.

Constraint values follow Optuna's rule: ``c ≤ 0`` is feasible, for every ``c``.
"""

from __future__ import annotations

from collections.abc import Mapping

from .._errors import InputDataError
from ..study._spec import StudySpec

__all__ = [
    "CONSTRAINT_NAMES",
    "constraint_values",
    "is_feasible",
    "meets_target",
    "refuse_model_effects",
    "relative_misfit",
]

CONSTRAINT_NAMES = ("theta_sat_min", "tcoat_max")


def relative_misfit(f60_n: float, target_n: float) -> float:
    """``|F60 / target − 1|``: the objective of a scalar F60 target."""
    return abs(f60_n / target_n - 1.0)


def constraint_values(
    params: Mapping[str, float],
    theta_sat_deg: float,
    spec: StudySpec,
    *,
    theta_margin_deg: float = 0.0,
) -> dict[str, float]:
    """Named constraint values of a point (``≤ 0`` feasible).

    ``theta_sat_min``: ``θmin − (θsat − margin)``, in degrees; the margin is the
    surrogate's uncertainty when the point is only predicted.
    ``tcoat_max``: ``Tcoat − fraction·t``, in mm.
    """
    values = {}
    rules = spec.constraints
    if rules.theta_sat_deg_min is not None:
        values["theta_sat_min"] = rules.theta_sat_deg_min - (theta_sat_deg - theta_margin_deg)
    if rules.tcoat_max_fraction_of_thickness is not None:
        limit = rules.tcoat_max_fraction_of_thickness * spec.rig.thickness_mm
        values["tcoat_max"] = float(params["tcoat_mm"]) - limit
    return values


def is_feasible(constraints: Mapping[str, float]) -> bool:
    """Feasible iff every constraint value is ≤ 0."""
    return all(value <= 0.0 for value in constraints.values())


def meets_target(misfit: float, constraints: Mapping[str, float], tolerance: float) -> bool:
    """A verified point meets the study: misfit within tolerance, every constraint met."""
    return misfit <= tolerance and is_feasible(constraints)


def refuse_model_effects(spec: StudySpec, command: str) -> None:
    """The main job identifies the bare coating: a study with ``[model] effects`` (known,
    a plug-in's or unknown) is refused in one line."""
    if spec.effects:
        raise InputDataError(
            f"{spec.path}: {command} works on the bare coating (the main job) and "
            f"cannot use [model] effects = {list(spec.effects)} (their parameters are "
            "calibrated against measured curves); remove them, or use surrogate calibrate "
            "/ compare / diagnose"
        )
