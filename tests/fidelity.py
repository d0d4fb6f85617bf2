"""A test-only "expensive" full solver: the built-in solver with a known smooth distortion.

``kind = "test-distorted"`` (registered by the fixture ``distorted_solver``): the
built-in curve of the same run times

    (1 + offset + slope·ln(D/D_REF)) · (1 + (bend + thick·ln(Tcoat/T_REF))·sin²θ)
        · (1 + rough·sin(RIPPLE·ln D))

with ``D`` the coat's bending stiffness [N·mm], ``θ`` the rotation. The defaults
(−3 %, +1 % per e-fold of D, +2 % towards 90°, no roughness) are the size of what
CalculiX's coarse mesh differs from the built-in rod by (README, cross-check), so the
multi-fidelity correction has a known, smooth target; ``offset`` beyond the trusted
correction and ``rough`` (a ripple in D far shorter than the discrepancy's length
scale) make the two cases it must refuse; ``thick`` a change of shape with Tcoat at fixed D
and Mp, which the built-in curves hardly show (CalculiX's coarse mesh does: 20 % more
Tcoat at the same D and Mp moved a fit's RMSE from 0.044 to 0.19 N); ``stiffened``
times the share an effect adds to Ecoat (the tension effect's ``kE·T``) more force —
a difference from the built-in model that only a model with the effect shows, as
CalculiX's gap grows with the end tension (F60 +9.5, +20.4 and +30.0 % at 0, 20 and
40 N, README). Like CalculiX it
refuses a bare-webbing stiffness (``membrane_bending``); ``fail_above_tcoat_mm`` makes
it fail where the coat is thicker, as ccx stops short for thick coats, and
``retry_above_tcoat_mm`` says of its runs there that they finished after a retry (the
result's ``retried_after``, as CalculiX's), its curve unchanged. Every run appends
its input hash and its process id to the file named by ``$SURROGATE_TEST_SOLVER_LOG``
(when set), so a test counts the expensive runs and sees where they ran.
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

import numpy as np
import pytest

from surrogate.physics import bending_stiffness
from surrogate.solvers import get_solver, model_state
from surrogate.solvers._base import _REGISTRY, Solver, failed_result, ok_result
from surrogate.solvers._cache import input_hash

LOG_VARIABLE = "SURROGATE_TEST_SOLVER_LOG"
D_REF_NMM = 8.6  # the paper's coat (1 GPa, 0.012 mm) on the 1.2 mm webbing
T_REF_MM = 0.012
RIPPLE = 60.0


class DistortedSolver(Solver):
    """The built-in solver's curve with a known smooth distortion (module docstring)."""

    name: ClassVar[str] = "test-distorted"
    version: ClassVar[str] = "test-distorted-1"
    settings_keys: ClassVar[tuple[str, ...]] = (
        "offset",
        "slope",
        "bend",
        "rough",
        "thick",
        "stiffened",
        "fail_above_tcoat_mm",
        "retry_above_tcoat_mm",
    )

    def refuses(self, state: Any) -> str | None:
        """Like CalculiX, no bare-webbing stiffness: a diagnosis skips membrane_bending."""
        if state.extra_stiffness_nmm:
            return "the test-distorted solver has no bare-webbing bending stiffness"
        return None

    def solve(self, inputs: dict[str, Any]) -> dict[str, Any]:
        log = os.environ.get(LOG_VARIABLE)
        if log:
            with open(log, "a", encoding="utf-8") as handle:
                handle.write(f"{input_hash(inputs)} {os.getpid()}\n")
        state = model_state(inputs)
        refused = self.refuses(state)
        if refused is not None:
            return failed_result(refused)
        settings = {"offset": -0.03, "slope": 0.01, "bend": 0.02, "rough": 0.0, "thick": 0.0}
        settings.update(inputs.get("solver_settings") or {})
        limit = settings.get("fail_above_tcoat_mm")
        if limit is not None and state.tcoat_mm > limit:
            return failed_result(f"stopped at 84.3° (a coat thicker than {limit} mm)")
        plain = {k: v for k, v in inputs.items() if k != "solver_settings"}
        result = get_solver("builtin").solve({**plain, "solver": "builtin"})
        if result["status"] != "ok":
            return result
        factor = distortion(inputs, np.asarray(result["angle_deg"]), settings)
        force = np.asarray(result["force_n"]) * factor
        perp = np.asarray(result["force_perp_n"]) * factor
        out = ok_result(np.asarray(result["angle_deg"]), force, perp)
        retry = settings.get("retry_above_tcoat_mm")
        if retry is not None and state.tcoat_mm > retry:  # as ccx's retries say it
            out["retried_after"] = f"with fixed increments: stopped (thicker than {retry} mm)"
        return out


def distortion(inputs: dict[str, Any], angle_deg: np.ndarray, settings: dict[str, float]):
    """The factor (per angle) the test solver multiplies the built-in curve by."""
    state = model_state(inputs)
    stiffness = bending_stiffness(state.ecoat_mpa, state.tcoat_mm, state.rig.thickness_mm)
    level = 1.0 + settings["offset"] + settings["slope"] * np.log(stiffness / D_REF_NMM)
    bend = settings["bend"] + settings.get("thick", 0.0) * np.log(state.tcoat_mm / T_REF_MM)
    shape = 1.0 + bend * np.sin(np.radians(angle_deg)) ** 2
    rough = 1.0 + settings["rough"] * np.sin(RIPPLE * np.log(stiffness))
    added = state.ecoat_mpa / (1000.0 * inputs["params"]["ecoat_gpa"]) - 1.0
    stiffened = 1.0 + settings.get("stiffened", 0.0) * added
    return level * shape * rough * stiffened


@pytest.fixture
def distorted_solver(monkeypatch):
    monkeypatch.setitem(_REGISTRY, DistortedSolver.name, DistortedSolver)
    return DistortedSolver
