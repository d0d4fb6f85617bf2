"""``simulate``: one full-solver run of the bending test with the built-in solver."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._errors import InputDataError, SolverError
from .._validate import check_positive
from ..effects import ModelState, get_effect
from ..physics import CoatingSection, curve_features, default_mesh, solve_rod, uniform_mesh
from ..study._conditions import check_conditions, rig_for
from ..study._rig import Rig
from ..study._units import gpa_to_mpa

__all__ = ["BendingCurve", "coating_state", "simulate"]


@dataclass(frozen=True)
class BendingCurve:
    """A force–rotation curve and its features.

    Attributes
    ----------
    angle_deg, force_n, force_perp_n : ndarray, shape (n,)
        Rotation on whole degrees, resultant probe force and its component
        perpendicular to the undeformed strip [N].
    f60_n, theta_sat_deg, saturated
        Features (see :func:`surrogate.physics.curve_features`).
    contact_arc_mm, clamp_moment_nmm : ndarray, shape (n,)
        Arc length from the clamp to the contact point; moment at the clamp.
    ecoat_gpa, scoat_gpa, tcoat_mm, rig
        The inputs.
    """

    angle_deg: np.ndarray
    force_n: np.ndarray
    force_perp_n: np.ndarray
    f60_n: float
    theta_sat_deg: float
    saturated: bool
    contact_arc_mm: np.ndarray
    clamp_moment_nmm: np.ndarray
    ecoat_gpa: float
    scoat_gpa: float
    tcoat_mm: float
    rig: Rig

    def to_json(self) -> dict[str, Any]:
        """The keys of ``surrogate simulate --json``."""
        return {
            "f60_n": self.f60_n,
            "theta_sat_deg": self.theta_sat_deg,
            "saturated": self.saturated,
            "angle_deg": self.angle_deg.tolist(),
            "force_n": self.force_n.tolist(),
            "force_perp_n": self.force_perp_n.tolist(),
        }


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


def simulate(
    ecoat_gpa: float,
    scoat_gpa: float,
    tcoat_mm: float,
    *,
    rig: Rig | None = None,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    conditions: Mapping[str, Any] | None = None,
    solver: str = "builtin",
    solver_settings: Mapping[str, Any] | None = None,
) -> BendingCurve:
    """Run a full solver of the 2-point bending test (the built-in one by default).

    Parameters
    ----------
    ecoat_gpa, scoat_gpa : float
        Coat Young's modulus and yield stress [GPa], > 0.
    tcoat_mm : float
        Coat layer thickness [mm], 0 < Tcoat < t/2.
    rig : Rig, optional
        The test rig; the default rig of design.md §3 when omitted.
    effects : mapping, optional
        Physical effects to switch on, with their parameters, e.g.
        ``{"hardening": {"ratio": 0.05}}`` (see :mod:`surrogate.effects`).
    conditions : mapping, optional
        Conditions of the test: ``tension_n``, ``direction`` (warp/weft),
        ``rate_deg_s``, ``bending_length_mm``, ``width_mm``.
    solver : {"builtin", "calculix", "lsdyna"}
        The full solver (:mod:`surrogate.solvers`); an external one reports
        no contact arc or clamp moment (NaN).
    solver_settings : mapping, optional
        Settings of an external solver, e.g. ``{"mesh": "fine"}``.

    Returns
    -------
    BendingCurve

    Raises
    ------
    InputDataError
        A value is out of range (the message names it and the allowed range).
    SolverError
        The solver did not converge (the message names the angle).
    """
    rig = Rig() if rig is None else rig
    if solver != "builtin" or solver_settings:
        return _external(
            solver, (ecoat_gpa, scoat_gpa, tcoat_mm), rig, effects, conditions, solver_settings
        )
    state = model_state_of(ecoat_gpa, scoat_gpa, tcoat_mm, rig, effects, conditions)
    rig = state.rig
    ratio = state.hardening_ratio
    section = CoatingSection(
        state.ecoat_mpa,
        state.scoat_mpa,
        state.tcoat_mm,
        rig.thickness_mm,
        hardening_modulus_mpa=state.ecoat_mpa * ratio / (1.0 - ratio),
        extra_stiffness_nmm=state.extra_stiffness_nmm,
    )
    angles = np.arange(0.0, np.floor(rig.max_angle_deg) + 1.0)
    if rig.element_size_mm is None:
        mesh = default_mesh(rig.free_length_mm, rig.bending_length_mm)
    else:
        mesh = uniform_mesh(rig.free_length_mm, rig.element_size_mm)
    solution = solve_rod(
        section,
        angles,
        segment_lengths_mm=mesh,
        width_mm=rig.width_mm,
        bending_length_mm=rig.bending_length_mm,
        contact_radius_mm=rig.contact_radius_mm,
        friction=rig.friction,
        tension_n=rig.tension_n,
        line_load_n_mm=state.line_load_n_mm,
        clamp_stiffness_nmm=state.clamp_stiffness_nmm,
    )
    features = curve_features(solution.angle_deg, solution.force_n)
    return BendingCurve(
        angle_deg=solution.angle_deg,
        force_n=solution.force_n,
        force_perp_n=solution.force_perp_n,
        f60_n=features.f60_n,
        theta_sat_deg=features.theta_sat_deg,
        saturated=features.saturated,
        contact_arc_mm=solution.contact_arc_mm,
        clamp_moment_nmm=solution.clamp_moment_nmm,
        ecoat_gpa=float(ecoat_gpa),
        scoat_gpa=float(scoat_gpa),
        tcoat_mm=float(tcoat_mm),
        rig=rig,
    )


def _external(
    solver: str,
    coating: tuple[float, float, float],
    rig: Rig,
    effects: Mapping[str, Mapping[str, float]] | None,
    conditions: Mapping[str, Any] | None,
    settings: Mapping[str, Any] | None,
) -> BendingCurve:
    """One run of a solver of :mod:`surrogate.solvers`; bad input raises before it starts."""
    from . import get_solver
    from ._base import model_state
    from ._batch import solver_inputs

    adapter = get_solver(solver)
    point = dict(zip(("ecoat_gpa", "scoat_gpa", "tcoat_mm"), coating, strict=True))
    inputs = solver_inputs(
        point,
        rig,
        solver=solver,
        effects=effects,
        conditions=conditions,
        solver_settings=adapter.check_settings(settings or {}),
    )
    state = model_state(inputs)
    result = adapter.solve(inputs)
    if result["status"] != "ok":
        raise SolverError(f"{solver}: {result['reason']}")
    angle = np.asarray(result["angle_deg"], dtype=float)
    return BendingCurve(
        angle_deg=angle,
        force_n=np.asarray(result["force_n"], dtype=float),
        force_perp_n=np.asarray(result["force_perp_n"], dtype=float),
        f60_n=result["f60_n"],
        theta_sat_deg=result["theta_sat_deg"],
        saturated=result["saturated"],
        contact_arc_mm=np.full_like(angle, np.nan),
        clamp_moment_nmm=np.full_like(angle, np.nan),
        ecoat_gpa=float(coating[0]),
        scoat_gpa=float(coating[1]),
        tcoat_mm=float(coating[2]),
        rig=state.rig,
    )
