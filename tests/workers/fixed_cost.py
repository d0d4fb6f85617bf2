"""A full-solver stand-in of fixed cost for the worker tests (and the benchmark).

Selectable only from code (``work(..., solve=FixedCostSolve(...))``), never from a
study file. Each call appends ``start <hash> <pid>`` and ``done <hash> <pid>``
to a log, so a test counts how often every run was started and finished.

Run as a worker: ``python -m tests.workers.fixed_cost STUDY STORAGE LOG COST_S
[JOBS] [HEARTBEAT_S] [--idle-timeout S] [--storage-patience S]
[--pause-at-first-heartbeat MARKER] [--cancelled]``.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from surrogate.solvers._cache import input_hash
from surrogate.storage._storage import STORAGE_PATIENCE_S


class FixedCostSolve:
    """Sleeps ``cost_s``, returns a smooth curve of the coating's stiffness."""

    def __init__(
        self,
        log: str | Path,
        cost_s: float,
        *,
        fail_above_tcoat_mm: float = np.inf,
        deaths: tuple[str | Path, int] | None = None,
        cancelled: bool = False,
    ):
        """``deaths = (folder, n)``: the first ``n`` solves (of any process) each write a
        file ``death-K`` into ``folder`` and die there (``os._exit``), as a worker the
        kernel killed."""
        self.log = str(log)
        self.cost_s = cost_s
        self.fail_above_tcoat_mm = fail_above_tcoat_mm
        self.deaths = None if deaths is None else (str(deaths[0]), deaths[1])
        self.cancelled = cancelled

    def _write(self, event: str, key: str) -> None:
        with open(self.log, "a", encoding="utf-8") as handle:
            handle.write(f"{event} {key} {os.getpid()}\n")

    def __call__(self, inputs: dict[str, Any]) -> dict[str, Any]:
        key = input_hash(inputs)
        self._write("start", key)
        if self.deaths is not None:
            folder, n = self.deaths
            for k in range(n):
                try:
                    (Path(folder) / f"death-{k}").touch(exist_ok=False)
                except FileExistsError:
                    continue
                os._exit(9)
        time.sleep(self.cost_s)
        if self.cancelled:  # as a job cancelled: its program dies first, the worker's signal after
            threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()
            raise RuntimeError("the solver's program was terminated")
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


def pause_at_first_heartbeat(marker: str | Path) -> None:
    """Make this process stop dead between its first claim and that trial's first
    heartbeat: it writes ``marker`` (the trial id) and sleeps until killed.

    The claim and the first heartbeat are two storage transactions; this makes
    the window between them one a test can hit every time.
    """
    from surrogate.identify import _worker

    start = _worker._Worker.__init__

    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        start(self, *args, **kwargs)

        def first_heartbeat(trial_id: int) -> None:
            Path(marker).write_text(f"{trial_id} {os.getpid()}\n")
            time.sleep(3600)

        self.storage.record_heartbeat = first_heartbeat

    _worker._Worker.__init__ = init


def main(argv: list[str]) -> int:
    import argparse

    from surrogate.identify._worker import work

    parser = argparse.ArgumentParser(prog="python -m tests.workers.fixed_cost")
    parser.add_argument("study")
    parser.add_argument("storage")
    parser.add_argument("log")
    parser.add_argument("cost_s", type=float)
    parser.add_argument("jobs", type=int, nargs="?", default=1)
    parser.add_argument("heartbeat_s", type=int, nargs="?", default=1)
    parser.add_argument("--idle-timeout", type=float, default=0.0)
    parser.add_argument("--storage-patience", type=float, default=STORAGE_PATIENCE_S)
    parser.add_argument("--pause-at-first-heartbeat", metavar="MARKER")
    parser.add_argument("--cancelled", action="store_true", help="each solve as a job cancelled")
    args = parser.parse_args(argv)
    if args.pause_at_first_heartbeat:
        pause_at_first_heartbeat(args.pause_at_first_heartbeat)
    result = work(
        args.study,
        storage=args.storage,
        jobs=args.jobs,
        heartbeat_s=args.heartbeat_s,
        idle_timeout_s=args.idle_timeout,
        storage_patience_s=args.storage_patience,
        solve=FixedCostSolve(args.log, args.cost_s, cancelled=args.cancelled),
        progress=False,
    )
    return 143 if result.interrupted == "SIGTERM" else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
