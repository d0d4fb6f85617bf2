"""The model state of one run: what every solver is given.

Coating (the paper's units, validated) + rig + the test's conditions + every
enabled effect → a :class:`surrogate.effects.ModelState` in solver units (MPa,
mm, N). The built-in solver, the CalculiX and the LS-DYNA adapters and the
calibration all take this one path, so an effect changes each of them alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .._errors import InputDataError
from .._validate import check_positive
from ..effects import ModelState, get_effect
from ..study import Rig, check_conditions, gpa_to_mpa, rig_for

__all__ = ["coating_state", "model_state", "model_state_of"]


def coating_state(ecoat_gpa: float, scoat_gpa: float, tcoat_mm: float, rig: Rig) -> ModelState:
    """Validate the coating values in the paper's units; the model state in MPa, mm."""
    ecoat = check_positive("ecoat_gpa", ecoat_gpa, unit="GPa")
    scoat = check_positive("scoat_gpa", scoat_gpa, unit="GPa")
    tcoat = check_positive("tcoat_mm", tcoat_mm, unit="mm")
    half = 0.5 * rig.thickness_mm
    if tcoat >= half:
        raise InputDataError(
            f"tcoat_mm must be < thickness_mm/2 = {half:g} mm (two coat layers fit in the "
            f"webbing), got {tcoat:g}"
        )
    return ModelState(gpa_to_mpa(ecoat), gpa_to_mpa(scoat), tcoat, rig)


def model_state_of(
    ecoat_gpa: float,
    scoat_gpa: float,
    tcoat_mm: float,
    rig: Rig,
    effects: Mapping[str, Mapping[str, float]] | None,
    conditions: Mapping[str, Any] | None,
) -> ModelState:
    """What a solver sees for one test: the coating validated, the rig of the test's
    conditions, every effect applied in turn (the one path for every solver)."""
    enabled = {name: get_effect(name) for name in (effects or {})}
    reads = [column for effect in enabled.values() for column in effect.reads]
    checked = check_conditions(conditions, read_by_effects=reads)
    state = coating_state(ecoat_gpa, scoat_gpa, tcoat_mm, rig_for(rig, checked))
    for name, values in (effects or {}).items():
        effect = enabled[name]
        state = effect.apply(state, effect.resolve(values), checked)
    return state


def model_state(inputs: Mapping[str, Any]) -> ModelState:
    """The model state of one run's inputs (:func:`surrogate.solvers.solver_inputs`):
    coating in MPa/mm, the rig of its conditions, every effect applied."""
    params = inputs["params"]
    return model_state_of(
        params["ecoat_gpa"],
        params["scoat_gpa"],
        params["tcoat_mm"],
        Rig(**inputs["rig"]),
        inputs.get("effects") or None,
        inputs.get("conditions") or None,
    )
