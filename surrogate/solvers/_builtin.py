"""The built-in rod solver behind the solver interface."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

from ..physics import SOLVER_VERSION
from ..study._rig import Rig
from ._base import Solver, guarded, register_solver
from ._simulate import simulate

__all__ = ["BuiltinSolver"]


@register_solver
class BuiltinSolver(Solver):
    """:func:`surrogate.simulate` (in-process, no settings)."""

    name: ClassVar[str] = "builtin"
    version: ClassVar[str] = SOLVER_VERSION

    def solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        return guarded(lambda: self._solve(inputs))

    def _solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        self.check_settings(inputs.get("solver_settings") or {})
        params = inputs["params"]
        curve = simulate(
            params["ecoat_gpa"],
            params["scoat_gpa"],
            params["tcoat_mm"],
            rig=Rig(**inputs["rig"]),
            effects=inputs.get("effects") or None,
            conditions=inputs.get("conditions") or None,
        )
        return {"status": "ok", "reason": "", **curve.to_json()}
