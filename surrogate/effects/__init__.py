"""Physical effects the model can be given (design.md §4)."""

from ._base import (
    Effect,
    EffectParameter,
    ModelState,
    available_effects,
    check_effects,
    get_effect,
    load_plugin,
    look_alikes,
    register_effect,
)

__all__ = [
    "Effect",
    "EffectParameter",
    "ModelState",
    "available_effects",
    "check_effects",
    "get_effect",
    "load_plugin",
    "look_alikes",
    "register_effect",
]
