"""A full-solver stand-in of fixed cost for the worker tests (and the benchmark).

Selectable only from code (``work(..., solve=FixedCostSolve(...))``), never from a
study file. Each call appends ``start <hash> <pid>`` and ``done <hash> <pid>``
to a log, so a test counts how often every run was started and finished.

Run as a worker: ``python -m tests.workers.fixed_cost STUDY STORAGE LOG COST_S
[JOBS] [HEARTBEAT_S]``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from surrogate.solvers._cache import input_hash


class FixedCostSolve:
    """Sleeps ``cost_s``, returns a smooth curve of the coating's stiffness."""

    def __init__(self, log: str | Path, cost_s: float, *, fail_above_tcoat_mm: float = np.inf):
        self.log = str(log)
        self.cost_s = cost_s
        self.fail_above_tcoat_mm = fail_above_tcoat_mm

    def _write(self, event: str, key: str) -> None:
        with open(self.log, "a", encoding="utf-8") as handle:
            handle.write(f"{event} {key} {os.getpid()}\n")

    def __call__(self, inputs: dict[str, Any]) -> dict[str, Any]:
        key = input_hash(inputs)
        self._write("start", key)
        time.sleep(self.cost_s)
        params = inputs["params"]
        if params["tcoat_mm"] > self.fail_above_tcoat_mm:
            raise RuntimeError(f"stand-in solver refuses Tcoat {params['tcoat_mm']:.3g} mm")
        angle = np.arange(0.0, 91.0)
        stiffness = params["ecoat_gpa"] * params["tcoat_mm"] * 1000.0
        force = stiffness * np.sin(np.radians(angle))
        self._write("done", key)
        return {
            "status": "ok",
            "reason": "",
            "f60_n": float(force[60]),
            "theta_sat_deg": 90.0,
            "saturated": False,
            "angle_deg": angle.tolist(),
            "force_n": force.tolist(),
            "force_perp_n": force.tolist(),
        }


def events(log: str | Path) -> list[tuple[str, str, int]]:
    """``(event, hash, pid)`` per line of a log."""
    path = Path(log)
    if not path.exists():
        return []
    return [
        (event, key, int(pid))
        for event, key, pid in (line.split() for line in path.read_text().splitlines())
    ]


def main(argv: list[str]) -> int:
    from surrogate.identify._worker import work

    study, storage, log, cost = argv[:4]
    jobs = int(argv[4]) if len(argv) > 4 else 1
    heartbeat = int(argv[5]) if len(argv) > 5 else 1
    result = work(
        study,
        storage=storage,
        jobs=jobs,
        heartbeat_s=heartbeat,
        idle_timeout_s=0.0,
        solve=FixedCostSolve(log, float(cost)),
        progress=False,
    )
    return 143 if result.interrupted == "SIGTERM" else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
