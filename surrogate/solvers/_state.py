"""The model state of one run: what every solver is given.

Coating (the paper's units, validated) + rig + the test's conditions + every
enabled effect → a :class:`surrogate.effects.ModelState` in solver units (MPa,
mm, N). The built-in solver, the CalculiX and the LS-DYNA adapters and the
calibration all take this one path, so an effect changes each of them alike.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from .._errors import InputDataError
from .._validate import check_positive
from ..effects import ModelState, get_effect
from ..physics import bending_stiffness, plastic_moment
from ..study import Rig, check_conditions, gpa_to_mpa, rig_for

__all__ = [
    "STATE_FEATURE_SPANS",
    "coating_state",
    "model_state",
    "model_state_of",
    "state_features",
]

#: The span over which each of :func:`state_features` typically varies (the paper's
#: ranges: D, Mp and the yield strain over about e⁴, Tcoat over e²; the ratios over
#: what the effects' ranges give): the unit of the low-to-high discrepancy's inputs.
STATE_FEATURE_SPANS = np.array([4.0, 4.0, 4.0, 2.0, 0.5, 1.0, 0.5, 1.0, 0.1, 10.0, 1.0, 1.0])


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
    reads = tuple(column for effect in enabled.values() for column in effect.reads)
    checked, test_rig = _test_rig(rig, conditions, reads)
    state = coating_state(ecoat_gpa, scoat_gpa, tcoat_mm, test_rig)
    for name, values in (effects or {}).items():
        effect = enabled[name]
        state = effect.apply(state, effect.resolve(values), checked)
    return state


def _test_rig(
    rig: Rig, conditions: Mapping[str, Any] | None, reads: tuple[str, ...]
) -> tuple[dict[str, Any], Rig]:
    """A test's checked conditions and its rig (:func:`check_conditions`,
    :func:`rig_for`), remembered for the few condition sets of a calibration: the
    search asks for the model state of ~10⁵ points at the same few tests. Conditions
    that cannot be a key (a plug-in column holding a list) are checked each time."""
    items = tuple((name, value, type(value)) for name, value in (conditions or {}).items())
    try:
        checked, test_rig = _checked_test_rig(rig, items, reads)
    except TypeError:  # unhashable: not remembered
        checked = check_conditions(conditions, read_by_effects=reads)
        return checked, rig_for(rig, checked)
    return dict(checked), test_rig  # a copy: an effect may not change what others see


@functools.lru_cache(maxsize=256)
def _checked_test_rig(
    rig: Rig, items: tuple[tuple[str, Any, type], ...], reads: tuple[str, ...]
) -> tuple[dict[str, Any], Rig]:
    """(keyed by each value's type too: 1 and 1.0 and True are one key otherwise)"""
    checked = check_conditions({n: v for n, v, _ in items}, read_by_effects=reads)
    return checked, rig_for(rig, checked)


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


def state_features(state: ModelState) -> np.ndarray:
    """What the solver sees, as surrogate inputs (physical, dimensionless where it helps).

    Every effect acts through the model state of a test (design.md §4), so a
    surrogate over the state serves every model and every test condition: the
    tension effect's ``Ecoat·(1 + kE·T)`` is just another stiffness to it.
    Features: log of the total bending stiffness, of the plastic moment, of the
    yield strain and of Tcoat; the hardening ratio; the bare webbing's share of
    the stiffness; the probe friction; the self-weight over the strip's
    stiffness (``q·L³/(D·b)``); the strip's stiffness over the clamp's
    (``D·b/(l·k)``); the end tension over the elastic force scale
    (``T·l²/(D·b)``); the bending length and the width.
    """
    rig = state.rig
    coat = bending_stiffness(state.ecoat_mpa, state.tcoat_mm, rig.thickness_mm)
    total = coat + state.extra_stiffness_nmm
    plastic = plastic_moment(state.scoat_mpa, state.tcoat_mm, rig.thickness_mm)
    flexural = total * rig.width_mm  # D·b [N·mm²]
    clamp = (
        0.0
        if state.clamp_stiffness_nmm is None
        else flexural / rig.bending_length_mm / state.clamp_stiffness_nmm
    )
    return np.array(
        [
            np.log(total),
            np.log(plastic),
            np.log(state.scoat_mpa / state.ecoat_mpa),
            np.log(state.tcoat_mm),
            state.hardening_ratio,
            state.extra_stiffness_nmm / total,
            rig.friction,
            state.line_load_n_mm * rig.free_length_mm**3 / flexural,
            clamp,
            rig.tension_n * rig.bending_length_mm**2 / flexural,
            np.log(rig.bending_length_mm),
            np.log(rig.width_mm),
        ]
    )
