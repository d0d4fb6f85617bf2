"""Wall time of a 40-run verification plan at 1, 2 and 4 workers, journal and PostgreSQL.

The solver is a stand-in of fixed cost (``--cost`` s of sleep per run), so the
figures measure the distribution itself: queueing, claiming, heartbeats and
telling through the storage, and the start of the worker processes
(``surrogate worker --jobs N`` = ``work(jobs=N)``). Scaling efficiency =
T(1) / (N · T(N)). PostgreSQL is a throwaway server (as in the tests).

    .venv/bin/python benchmarks/workers.py            # --runs 40 --cost 0.5
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks._machine import machine  # noqa: E402
from surrogate.identify._doe import make_design  # noqa: E402
from surrogate.identify._verify import enqueue, finished_records, open_verify_study  # noqa: E402
from surrogate.identify._worker import work  # noqa: E402
from surrogate.study._spec import load_study  # noqa: E402
from tests.components import ComponentMissing, create_database, throwaway_postgres  # noqa: E402


class SleepSolve:
    """A full-solver stand-in that costs ``cost_s`` seconds and returns a flat curve."""

    def __init__(self, cost_s: float) -> None:
        self.cost_s = cost_s

    def __call__(self, inputs: dict[str, Any]) -> dict[str, Any]:
        time.sleep(self.cost_s)
        force = [inputs["params"]["ecoat_gpa"]] * 91
        return {
            "status": "ok",
            "reason": "",
            "f60_n": force[60],
            "theta_sat_deg": 90.0,
            "saturated": False,
            "angle_deg": list(range(91)),
            "force_n": force,
            "force_perp_n": force,
        }


def _one(folder: Path, storage: str, runs: int, workers: int, cost_s: float) -> float:
    """Seconds from starting ``workers`` worker processes until the plan is done.

    Each measurement has its own folder, so its result cache starts empty.
    """
    folder.mkdir()
    shutil.copy(ROOT / "studies" / "paper_coating.toml", folder / "study.toml")
    spec = load_study(folder / "study.toml")
    study = open_verify_study(spec, storage, heartbeat_s=None)
    points = make_design("lhs", spec.space, n=runs, seed=0).to_dict("records")
    keys = enqueue(study, spec, points, phase="benchmark")
    start = time.perf_counter()
    result = work(
        spec,
        storage=storage,
        jobs=workers,
        idle_timeout_s=0.0,
        solve=SleepSolve(cost_s),
        progress=False,
    )
    elapsed = time.perf_counter() - start
    done = finished_records(study, keys)
    if result.runs != runs or len(done) != runs:
        raise SystemExit(f"plan not finished exactly once: {result.runs} runs, {len(done)} done")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--cost", type=float, default=0.5, help="seconds per solver run")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="surrogate-bench-") as tmp:
        folder = Path(tmp)
        try:
            postgres = throwaway_postgres()
            server = postgres.__enter__()
        except ComponentMissing as error:
            print(f"PostgreSQL skipped: {error}", file=sys.stderr)
            postgres = server = None
        try:
            for kind in ("journal", "postgresql"):
                if kind == "postgresql" and server is None:
                    continue
                times = {}
                for n in args.workers:
                    storage = (
                        f"journal://{folder / f'plan-{n}.log'}"
                        if kind == "journal"
                        else create_database(server, f"plan_{n}")
                    )
                    times[n] = _one(folder / f"{kind}-{n}", storage, args.runs, n, args.cost)
                rows += [(kind, n, t, times[args.workers[0]] / (n * t)) for n, t in times.items()]
        finally:
            if postgres is not None:
                postgres.__exit__(None, None, None)
    ideal = args.runs * args.cost
    print(
        f"{args.runs}-run plan, fixed solver cost {args.cost:g} s (serial solver time {ideal:g} s)"
    )
    header = f"{'storage':<11} {'workers':>7} {'wall time':>10} {'efficiency':>11}"
    print(f"{header} {'overhead/run':>13}")
    for kind, n, seconds, efficiency in rows:
        # what a worker spends on a run besides the solver: claim, heartbeat, tell
        overhead = n * seconds / args.runs - args.cost
        print(
            f"{kind:<11} {n:>7} {seconds:>9.2f}s {100 * efficiency:>10.0f}% "
            f"{1000 * overhead:>10.0f} ms"
        )
    print(f"machine: {machine()}")


if __name__ == "__main__":
    main()
