"""The built-in effects of design.md §4 (those the built-in solver supports)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from .._errors import InputDataError
from ._base import Effect, EffectParameter, ModelState, register_effect

__all__ = [
    "Anisotropy",
    "ClampSlip",
    "Friction",
    "Gravity",
    "Hardening",
    "MembraneBending",
    "Rate",
    "Tension",
]

REFERENCE_RATE_DEG_S = 90.0
STANDARD_GRAVITY_M_S2 = 9.80665


class Tension(Effect):
    name = "tension"
    description = "coating stiffens with webbing tension: Ecoat·(1+kE·T), Scoat·(1+kS·T)"
    parameters = (
        EffectParameter("k_e", 0.0, 0.2, 0.0, "1/N"),
        EffectParameter("k_s", 0.0, 0.2, 0.0, "1/N"),
    )
    reads = ("tension_n",)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        tension = float(conditions.get("tension_n", 0.0))
        return state.replace(
            ecoat_mpa=state.ecoat_mpa * (1 + values["k_e"] * tension),
            scoat_mpa=state.scoat_mpa * (1 + values["k_s"] * tension),
        )


class Hardening(Effect):
    name = "hardening"
    description = "linear hardening of the coat instead of ideal plasticity (H/Ecoat)"
    parameters = (EffectParameter("ratio", 0.0, 0.5, 0.0),)
    # linear kinematic hardening is, section for section, an elastic spring in parallel with
    # an ideal-plastic coat: membrane bending's moment–curvature law (README)
    look_alikes = ("membrane_bending",)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        return state.replace(hardening_ratio=values["ratio"])


class Anisotropy(Effect):
    name = "anisotropy"
    description = "coating scaled by aE, aS in the weft direction"
    parameters = (EffectParameter("a_e", 0.2, 5.0, 1.0), EffectParameter("a_s", 0.2, 5.0, 1.0))
    reads = ("direction",)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        if conditions.get("direction", "warp") != "weft":
            return state
        return state.replace(
            ecoat_mpa=state.ecoat_mpa * values["a_e"], scoat_mpa=state.scoat_mpa * values["a_s"]
        )


class Rate(Effect):
    name = "rate"
    description = "log-rate scaling of Ecoat, Scoat around 90°/s"
    parameters = (EffectParameter("c_e", 0.0, 0.3, 0.0), EffectParameter("c_s", 0.0, 0.3, 0.0))
    reads = ("rate_deg_s",)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        rate = float(conditions.get("rate_deg_s", REFERENCE_RATE_DEG_S))
        if rate <= 0:
            raise InputDataError(f"rate_deg_s must be > 0, got {rate:g}")
        log_ratio = math.log(rate / REFERENCE_RATE_DEG_S)
        scale_e = 1 + values["c_e"] * log_ratio
        scale_s = 1 + values["c_s"] * log_ratio
        if scale_e <= 0 or scale_s <= 0:
            raise InputDataError(f"rate effect makes the coat vanish at {rate:g}°/s; lower c_e/c_s")
        return state.replace(
            ecoat_mpa=state.ecoat_mpa * scale_e, scoat_mpa=state.scoat_mpa * scale_s
        )


class MembraneBending(Effect):
    name = "membrane_bending"
    description = "bending stiffness of the bare webbing, D0 per unit width"
    parameters = (EffectParameter("d0_nmm", 0.0, 50.0, 0.0, "N·mm"),)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        return state.replace(extra_stiffness_nmm=state.extra_stiffness_nmm + values["d0_nmm"])


class Friction(Effect):
    name = "friction"
    description = "probe friction as a calibrated parameter"
    parameters = (EffectParameter("mu", 0.0, 0.8, math.nan),)  # off: the rig's own μ

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        if math.isnan(values["mu"]):
            return state
        return state.replace(rig=state.rig.replace(friction=values["mu"]))


class Gravity(Effect):
    name = "gravity"
    description = (
        "self-weight of the strip (areal mass), acting downwards, away from the probe: "
        "the strip sags and touches the probe only after some rotation"
    )
    parameters = (EffectParameter("areal_mass_g_m2", 0.0, 20000.0, 0.0, "g/m²"),)
    reads = ("width_mm",)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        # g/m² → N/mm² is ·1e-3 kg/g · g₀ · 1e-6 m²/mm²; times the width: N/mm.
        pressure = values["areal_mass_g_m2"] * 1e-9 * STANDARD_GRAVITY_M_S2
        return state.replace(line_load_n_mm=state.line_load_n_mm + pressure * state.rig.width_mm)


class ClampSlip(Effect):
    name = "clamp_slip"
    description = (
        "rotational compliance in the clamp: a spring k per unit width between the fixture "
        "and the strip (softens the rise at small angles)"
    )
    parameters = (EffectParameter("k_nmm_rad", 2.0, 2000.0, math.inf, "N·mm/rad per mm", log=True),)

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:
        if math.isinf(values["k_nmm_rad"]):
            return state
        return state.replace(clamp_stiffness_nmm=values["k_nmm_rad"] * state.rig.width_mm)


for _effect in (
    Tension,
    Hardening,
    Anisotropy,
    Rate,
    MembraneBending,
    Friction,
    Gravity,
    ClampSlip,
):
    register_effect(_effect)
