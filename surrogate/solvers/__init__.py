"""The full-solver contract: model state, the solvers, batch evaluation, result cache.

- **Model state** (``_state``): coating + rig + conditions + effects →
  :func:`model_state_of` / :func:`model_state`, the one path from a run's
  inputs to what every solver models; :func:`state_features`, that state as
  surrogate inputs.
- **Solvers** behind one interface (``_base``): ``get_solver(kind).solve(inputs)``
  turns the plain-JSON inputs of a run into its plain-JSON result (a failure is
  a result); ``run(inputs)`` raises it instead. The kinds register here:
  ``builtin`` (the rod of :mod:`surrogate.physics`, ``_builtin``), ``calculix``
  (``_calculix``) and ``lsdyna`` (``_lsdyna``); :func:`available_solvers` is
  the one list of kinds.
- **One run** (``_simulate``): :func:`simulate` → a :class:`BendingCurve`.
- **Batch evaluation** (``_batch``): :func:`solver_inputs` (the one definition
  of a run's inputs, solver settings included), :func:`solve_inputs`,
  :func:`evaluate_design` over the package's process pool.
- **Result cache** (``_cache``): :class:`ResultCache` keyed by :func:`input_hash`.

Nothing here imports a command (identification, calibration, storage, CLI).
"""

# The adapters register in the order they are imported: builtin, calculix, lsdyna.
from ._base import Solver, available_solvers, get_solver, register_solver
from ._batch import evaluate_design, solve_inputs, solver_inputs
from ._builtin import BuiltinSolver
from ._cache import ResultCache, input_hash
from ._calculix import CALCULIX_MESHES, CalculixSolver, calculix_deck, parse_calculix_dat
from ._lsdyna import (
    LsDynaSolver,
    coating_parameters,
    fill_parameters,
    fill_seatbelt_card,
    parse_nodout_rotation,
    parse_rcforc,
)
from ._simulate import BendingCurve, simulate
from ._state import STATE_FEATURE_SPANS, coating_state, model_state, model_state_of, state_features

__all__ = [
    "CALCULIX_MESHES",
    "STATE_FEATURE_SPANS",
    "BendingCurve",
    "BuiltinSolver",
    "CalculixSolver",
    "LsDynaSolver",
    "ResultCache",
    "Solver",
    "available_solvers",
    "calculix_deck",
    "coating_parameters",
    "coating_state",
    "evaluate_design",
    "fill_parameters",
    "fill_seatbelt_card",
    "get_solver",
    "input_hash",
    "model_state",
    "model_state_of",
    "parse_calculix_dat",
    "parse_nodout_rotation",
    "parse_rcforc",
    "register_solver",
    "simulate",
    "solve_inputs",
    "solver_inputs",
    "state_features",
]
