"""The built-in rod solver (:mod:`surrogate.physics`) behind the solver interface.

From the model state of one run (:func:`surrogate.solvers.model_state`) to the
coating section, the mesh of the rig, the rod solved on whole degrees, and the
plain-JSON result (with the contact arc and the clamp moment, which only this
solver reports).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .. import physics
from ..effects import ModelState
from ..physics import SOLVER_VERSION
from ..study import Rig
from ._base import Solver, guarded, ok_result, register_solver
from ._state import model_state

if TYPE_CHECKING:  # the rod loads with the first solve (numba): surrogate.physics
    from ..physics import CoatingSection, RodSolution

__all__ = ["BuiltinSolver", "coating_section", "rod_mesh", "solve_state"]


def coating_section(state: ModelState) -> CoatingSection:
    """The moment–curvature law of the coated strip of ``state`` (hardening and the
    extra bending stiffness of the effects included)."""
    ratio = state.hardening_ratio
    return physics.CoatingSection(
        state.ecoat_mpa,
        state.scoat_mpa,
        state.tcoat_mm,
        state.rig.thickness_mm,
        hardening_modulus_mpa=state.ecoat_mpa * ratio / (1.0 - ratio),
        extra_stiffness_nmm=state.extra_stiffness_nmm,
    )


def rod_mesh(rig: Rig) -> np.ndarray:
    """Segment lengths of the free strip: graded by default, uniform at ``element_size_mm``."""
    if rig.element_size_mm is None:
        return physics.default_mesh(rig.free_length_mm, rig.bending_length_mm)
    return physics.uniform_mesh(rig.free_length_mm, rig.element_size_mm)


def solve_state(state: ModelState) -> RodSolution:
    """Rotate the clamp of ``state.rig`` from 0° to its range in whole degrees.

    Raises
    ------
    SolverError
        The rod did not converge, or the strip slid off the probe (the message
        names the angle).
    """
    rig = state.rig
    return physics.solve_rod(
        coating_section(state),
        np.arange(0.0, np.floor(rig.max_angle_deg) + 1.0),
        segment_lengths_mm=rod_mesh(rig),
        width_mm=rig.width_mm,
        bending_length_mm=rig.bending_length_mm,
        contact_radius_mm=rig.contact_radius_mm,
        friction=rig.friction,
        tension_n=rig.tension_n,
        line_load_n_mm=state.line_load_n_mm,
        clamp_stiffness_nmm=state.clamp_stiffness_nmm,
    )


def _result(solution: RodSolution) -> dict[str, Any]:
    """The plain-JSON result of a solved rod: features, curve, contact arc, clamp moment."""
    return ok_result(
        solution.angle_deg,
        solution.force_n,
        solution.force_perp_n,
        contact_arc_mm=solution.contact_arc_mm,
        clamp_moment_nmm=solution.clamp_moment_nmm,
    )


@register_solver
class BuiltinSolver(Solver):
    """The rod of :mod:`surrogate.physics`, in this process, no settings."""

    name: ClassVar[str] = "builtin"
    version: ClassVar[str] = SOLVER_VERSION

    def solve(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        return guarded(lambda: self.run(inputs))

    def run(self, inputs: Mapping[str, Any]) -> dict[str, Any]:
        """One run; bad input raises InputDataError, a failed solve the rod's own
        SolverError (its message names the angle)."""
        self.check_settings(inputs.get("solver_settings") or {})
        return _result(solve_state(model_state(inputs)))
