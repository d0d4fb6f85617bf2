"""Full solvers behind one interface: ``builtin``, ``calculix``, ``lsdyna``.

``get_solver(kind).solve(inputs)`` turns the plain-JSON inputs of a run into
its plain-JSON result (see :mod:`surrogate.solvers._base`).
"""

from ._base import Solver, available_solvers, get_solver, register_solver
from ._builtin import BuiltinSolver
from ._calculix import CALCULIX_MESHES, CalculixSolver, calculix_deck, parse_calculix_dat
from ._lsdyna import (
    LsDynaSolver,
    coating_parameters,
    fill_parameters,
    fill_seatbelt_card,
    parse_nodout_rotation,
    parse_rcforc,
)

__all__ = [
    "CALCULIX_MESHES",
    "BuiltinSolver",
    "CalculixSolver",
    "LsDynaSolver",
    "Solver",
    "available_solvers",
    "calculix_deck",
    "coating_parameters",
    "fill_parameters",
    "fill_seatbelt_card",
    "get_solver",
    "parse_calculix_dat",
    "parse_nodout_rotation",
    "parse_rcforc",
    "register_solver",
]
