"""``simulate``: one full-solver run of the bending test, as a :class:`BendingCurve`.

Every solver kind takes the same path: the inputs checked and turned into the
plain-JSON run of :func:`surrogate.solvers.solver_inputs`, then
``get_solver(kind).run(inputs)``; bad input raises before a solve starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._pool import one_blas_thread_within
from ..study import Rig
from ._base import get_solver
from ._batch import solver_inputs
from ._state import model_state_of

__all__ = ["BendingCurve", "simulate"]


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


@one_blas_thread_within
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
    solver : str
        A registered full solver (:func:`surrogate.solvers.available_solvers`:
        ``builtin``, ``calculix``, ``lsdyna``); an external one reports no
        contact arc or clamp moment (NaN).
    solver_settings : mapping, optional
        Settings of an external solver, e.g. ``{"mesh": "fine"}``.

    Returns
    -------
    BendingCurve

    Raises
    ------
    InputDataError
        A value is out of range (the message names it and the allowed range),
        raised before a solve starts.
    SolverError
        The run failed: the built-in solver did not converge (the message
        names the angle), or an external one failed (the message starts with
        its name).
    """
    rig = Rig() if rig is None else rig
    coating = {"ecoat_gpa": ecoat_gpa, "scoat_gpa": scoat_gpa, "tcoat_mm": tcoat_mm}
    result, checked_rig = solve_checked(
        coating, rig, solver, effects, conditions, solver_settings or {}
    )
    return _curve(result, coating, checked_rig)


def solve_checked(
    coating: dict[str, float],
    rig: Rig,
    solver: str,
    effects: Mapping[str, Mapping[str, float]] | None,
    conditions: Mapping[str, Any] | None,
    settings: Mapping[str, Any],
) -> tuple[dict[str, Any], Rig]:
    """:func:`simulate`'s run: an InputDataError (the solver kind, its settings, the
    coating, conditions, effects) before anything is solved; then the solver's whole
    result (a benchmark reads more of it than the curve: CalculiX's ``increments``) and
    the rig of the test's conditions."""
    checked_settings = get_solver(solver).check_settings(settings)
    state = model_state_of(
        coating["ecoat_gpa"], coating["scoat_gpa"], coating["tcoat_mm"], rig, effects, conditions
    )
    inputs = solver_inputs(
        coating,
        rig,
        solver=solver,
        effects=effects,
        conditions=conditions,
        solver_settings=checked_settings,
    )
    return get_solver(solver).run(inputs), state.rig


def _curve(result: Mapping[str, Any], coating: Mapping[str, float], rig: Rig) -> BendingCurve:
    """A successful result as a :class:`BendingCurve`; a solver that reports no contact
    arc or clamp moment (an external one) gets NaN there."""
    angle = np.asarray(result["angle_deg"], dtype=float)
    return BendingCurve(
        angle_deg=angle,
        force_n=np.asarray(result["force_n"], dtype=float),
        force_perp_n=np.asarray(result["force_perp_n"], dtype=float),
        f60_n=result["f60_n"],
        theta_sat_deg=result["theta_sat_deg"],
        saturated=result["saturated"],
        contact_arc_mm=_optional(result, "contact_arc_mm", angle),
        clamp_moment_nmm=_optional(result, "clamp_moment_nmm", angle),
        ecoat_gpa=float(coating["ecoat_gpa"]),
        scoat_gpa=float(coating["scoat_gpa"]),
        tcoat_mm=float(coating["tcoat_mm"]),
        rig=rig,
    )


def _optional(result: Mapping[str, Any], key: str, angle_deg: np.ndarray) -> np.ndarray:
    if key not in result:
        return np.full_like(angle_deg, np.nan)
    return np.asarray(result[key], dtype=float)
