"""What the report says of a study's full solver: its version, settings and verification.

The verification figures are those the benchmarks measured for one solver version
(README, "The full solver" and "Cross-check: built-in vs CalculiX"); they are shown
only for that version — a solver whose results changed has a new version and no
figures until the benchmark is run again, and the report says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..solvers._base import result_settings
from ..solvers._batch import solver_version
from ..study._spec import StudySpec

__all__ = ["VERIFIED", "SolverFacts", "solver_facts"]

Figure = tuple[str, str, str]  # (check, measured, target)

VERIFIED: dict[tuple[str, str], tuple[str, tuple[Figure, ...]]] = {
    ("builtin", "rod-2"): (
        "benchmarks/solver.py against the references of design.md §3 (tests/reference), "
        "2-core AMD EPYC",
        (
            (
                "worst error against the elastica (μ = 0, 0.2, 0.4), the cantilever, "
                "the small-angle and the rigid-plastic limits",
                "0.083 %",
                "≤ 0.5 %",
            ),
            ("curve RMS error at the default mesh against 8× finer", "0.030 % (order 1.97)", ""),
            ("F60 with the system-model mesh (element_size_mm = 2.5)", "−1.0 %", ""),
        ),
    ),
    ("calculix", "ccx-deck-5"): (
        "benchmarks/solvers.py, fine mesh against the built-in solver, default rig (measured "
        "with deck 4; deck 5 re-runs only a run that stopped short, these reached 90°)",
        (
            ("F60, elastic coat (Ecoat 1 GPa, Tcoat 0.012 mm, μ = 0)", "−2.05 %", "within 5 %"),
            (
                "F60, yielding coat (Ecoat 1, Scoat 0.12 GPa, Tcoat 0.02 mm)",
                "−3.16 %",
                "within 5 %",
            ),
            ("F60, elastic coat with μ = 0.3", "−1.62 %", ""),
            ("coarse mesh: F60 against 0.1 mm elements (paper optimum)", "+0.5 %", ""),
        ),
    ),
}
"""Verification figures by (solver, version): where they come from, and the figures."""

_UNVERIFIED = {
    "lsdyna": "LS-DYNA is not available where this product is tested: the adapter is tested "
    "on files in LS-DYNA's documented formats only, never against a real LS-DYNA run. "
    "Check one run of your deck against a result you trust before signing off.",
}


@dataclass(frozen=True)
class SolverFacts:
    """A study's full solver: ``result_settings`` name a run (they enter its hash),
    ``run_settings`` only say how to run it; ``figures`` are its verification figures
    (empty: none recorded for this version, ``remark`` says why or what instead)."""

    kind: str
    version: str
    result_settings: dict[str, Any]
    run_settings: dict[str, Any]
    source: str
    figures: tuple[Figure, ...]
    remark: str


def solver_facts(spec: StudySpec) -> SolverFacts:
    """What the report says of the full solver of ``spec``."""
    kind, settings = spec.solver, spec.solver_settings
    version = solver_version(kind)
    named = result_settings(kind, settings)
    source, figures = VERIFIED.get((kind, version), ("", ()))
    remark = _UNVERIFIED.get(kind, "")
    if not figures and not remark:
        remark = (
            f"No verification figures are recorded for {kind} version {version}; run its "
            "benchmark (benchmarks/solver.py, benchmarks/solvers.py) before signing off."
        )
    return SolverFacts(
        kind=kind,
        version=version,
        result_settings=named,
        run_settings={k: v for k, v in sorted(settings.items()) if k not in named},
        source=source,
        figures=figures,
        remark=remark,
    )
