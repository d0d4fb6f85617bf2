"""Physical effects: small objects that change the physics of one test.

An effect has a name, declared parameters (bounds, units, the value that
switches it off), the test conditions it reads, and :meth:`Effect.apply`, which
turns the model state of one test into a new one. Built-ins live in
``_builtin.py``; users register their own with :func:`register_effect` from a
module they name explicitly (``--plugin my_effects``) — code is never loaded
from a study file's contents.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from .._errors import InputDataError
from ..study import Rig

__all__ = [
    "Effect",
    "EffectParameter",
    "ModelState",
    "available_effects",
    "check_effects",
    "get_effect",
    "load_plugin",
    "register_effect",
]


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect: bounds, unit, and the value that means "off"
    (NaN: leave the model as it is, e.g. keep the rig's friction)."""

    name: str
    low: float
    high: float
    off: float
    unit: str = ""
    log: bool = False


@dataclass(frozen=True)
class ModelState:
    """What the full solver needs for one test, in solver units (MPa, mm, N).

    ``hardening_ratio`` is the coat's post-yield tangent modulus over Ecoat;
    ``extra_stiffness_nmm`` an elastic bending stiffness per unit width added
    to the coat's (e.g. the bare webbing's own); ``line_load_n_mm`` the strip's
    self-weight per unit length, full width; ``clamp_stiffness_nmm`` the
    clamp's rotational stiffness, full width [N·mm/rad] (``None``: rigid).
    """

    ecoat_mpa: float
    scoat_mpa: float
    tcoat_mm: float
    rig: Rig
    hardening_ratio: float = 0.0
    extra_stiffness_nmm: float = 0.0
    line_load_n_mm: float = 0.0
    clamp_stiffness_nmm: float | None = None

    def replace(self, **changes: Any) -> ModelState:
        """A copy with some fields changed: ``dataclasses.replace``'s result, without its
        ``__init__`` of every field (a calibration's search replaces ~10⁶ states)."""
        if type(self) is not ModelState or not changes.keys() <= _STATE_FIELDS:
            return dataclasses.replace(self, **changes)  # a subclass; its TypeError
        copy = object.__new__(ModelState)
        copy.__dict__.update(self.__dict__)
        copy.__dict__.update(changes)
        return copy


_STATE_FIELDS = frozenset(field.name for field in dataclasses.fields(ModelState))


class Effect:
    """Base class of physical effects (subclass it; see ``_builtin.py``)."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    parameters: ClassVar[tuple[EffectParameter, ...]] = ()
    reads: ClassVar[tuple[str, ...]] = ()
    #: effects that can give the same curves (the same law in another guise), declared on
    #: one side of each pair (:func:`look_alikes` reads both): where one of a pair leads a
    #: diagnosis the other is recalibrated over the whole space before a tie is judged
    look_alikes: ClassVar[tuple[str, ...]] = ()

    def apply(
        self, state: ModelState, values: Mapping[str, float], conditions: Mapping[str, Any]
    ) -> ModelState:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- shared validation ---------------------------------------------------------------------
    def resolve(self, values: Mapping[str, float] | None) -> dict[str, float]:
        """Full parameter values (missing ones at "off"), validated against the bounds."""
        values = values or {}
        names = [p.name for p in self.parameters]
        unknown = [k for k in values if k not in names]
        if unknown:
            raise InputDataError(
                f"effect {self.name!r} has no parameter {unknown[0]!r}; "
                f"its parameters: {', '.join(names) or 'none'}"
            )
        resolved = {}
        for p in self.parameters:
            if p.name not in values:
                resolved[p.name] = p.off  # "off" may lie outside the bounds (NaN, inf)
                continue
            value = values[p.name]
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InputDataError(
                    f"{self.name}.{p.name} must be a number, got {value!r}"
                ) from None
            if not (p.low <= value <= p.high):
                raise InputDataError(
                    f"{self.name}.{p.name} must be in [{p.low:g}, {p.high:g}]"
                    f"{' ' + p.unit if p.unit else ''}, got {value:g}"
                )
            resolved[p.name] = value
        return resolved


_REGISTRY: dict[str, Effect] = {}


def register_effect(effect: Effect | type[Effect]) -> Effect:
    """Make an effect available by its name (an instance or a class)."""
    instance = effect() if isinstance(effect, type) else effect
    if not isinstance(instance, Effect) or not instance.name.isidentifier():
        raise InputDataError(
            f"an effect needs a subclass of surrogate.Effect with a name that "
            f"is an identifier, got {effect!r}"
        )
    _REGISTRY[instance.name] = instance
    return instance


def get_effect(name: str) -> Effect:
    registry = _registry()
    if name not in registry:
        raise InputDataError(
            f"unknown effect {name!r}; available: "
            f"{', '.join(sorted(registry))} (or load a plug-in with --plugin)"
        )
    return registry[name]


def look_alikes(name: str) -> set[str]:
    """The registered effects that are look-alikes of ``name``: those it declares and those
    declaring it (the relation is symmetric; each pair is declared once)."""
    registry = _registry()
    declared = set(registry[name].look_alikes) if name in registry else set()
    return declared | {other for other, e in registry.items() if name in e.look_alikes}


def check_effects(names: Iterable[str], plugins: Iterable[str] = ()) -> tuple[str, ...]:
    """``names`` if each is a registered effect once ``plugins`` are imported; else the
    one-line error of the first unknown (every command that reads a study's
    ``[model] effects`` checks them with this)."""
    for module in plugins:
        load_plugin(module)
    names = tuple(names)
    for name in names:
        get_effect(name)
    return names


def available_effects() -> list[str]:
    return sorted(_registry())


_BUILTINS_LOADED = False


def _registry() -> dict[str, Effect]:
    """The registered effects, the built-ins among them: imported on the first call only
    (an import statement each call cost a calibration's search about as much as the
    effects themselves did)."""
    global _BUILTINS_LOADED
    if not _BUILTINS_LOADED:
        from . import _builtin  # noqa: F401

        _BUILTINS_LOADED = True
    return _REGISTRY


def load_plugin(module: str) -> None:
    """Import a user's module of effects by its name (it calls :func:`register_effect`)."""
    if not all(part.isidentifier() for part in module.split(".")):
        raise InputDataError(
            f"--plugin takes a Python module name such as my_effects, got {module!r}"
        )
    here = os.getcwd()
    if here not in sys.path:  # "in the working folder", as the message below says
        sys.path.append(here)
    try:
        importlib.import_module(module)
    except ImportError as error:
        raise InputDataError(
            f"cannot import plug-in module {module!r} ({error}); put it on "
            "PYTHONPATH or in the working folder"
        ) from None
