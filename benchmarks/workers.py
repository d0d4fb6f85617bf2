"""Wall time of a 40-run verification plan at 1, 2 and 4 workers, journal and PostgreSQL.

The solver is a stand-in of fixed cost (``--cost`` s of sleep per run), so the
figures measure the distribution itself: queueing, claiming, heartbeats and
telling through the storage, and the start of the worker processes
(``surrogate worker --jobs N`` = ``work(jobs=N)``). Scaling efficiency =
T(1) / (N · T(N)). PostgreSQL is a throwaway server (as in the tests).

    .venv/bin/python benchmarks/workers.py            # --runs 40 --cost 0.5

``--slurm``: runs per hour of local workers and of Slurm jobs side by side, on the same
plan and the same fixed-cost solver — the LS-DYNA stand-in (tests/solvers/fixtures/
fake_lsdyna.py, NOT LS-DYNA: ``--cost`` s of sleep plus its own start and solve) as
an external process, through the real worker (``surrogate worker``) and PostgreSQL.
Local: ``work(jobs=N)``; Slurm: the planner's dispatcher and fleet (``--launcher
slurm``: one job a run, at most N at once) on the cluster ``sbatch`` reaches, else a
throwaway single-node one (root, slurm-wlm). The scheduler's overhead per run =
N · (T_slurm − T_local) / runs: the job's start, the worker's start and its storage.

    .venv/bin/python benchmarks/workers.py --slurm    # --runs 12 --cost 2 --workers 2
"""

from __future__ import annotations

import argparse
import json
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


def _stand_in_study(folder: Path) -> Path:
    """The paper's study with the LS-DYNA stand-in as its full solver (no built-in prior:
    every run of the plan is a stand-in run)."""
    fixtures = ROOT / "tests" / "solvers" / "fixtures"
    command = json.dumps([sys.executable, str(fixtures / "fake_lsdyna.py")])
    text = (ROOT / "studies" / "paper_coating.toml").read_text()
    text = text.replace(
        'kind = "builtin"',
        f'kind = "lsdyna"\ntemplate = "{fixtures / "bending_template.k"}"\n'
        f"command = {command}\nmulti_fidelity = false",
    )
    folder.mkdir()
    (folder / "study.toml").write_text(text)
    return folder / "study.toml"


def _plan(folder: Path, storage: str, runs: int) -> tuple[Any, Any, list[dict[str, float]]]:
    spec = load_study(_stand_in_study(folder))
    study = open_verify_study(spec, storage, heartbeat_s=None)
    return spec, study, make_design("lhs", spec.space, n=runs, seed=0).to_dict("records")


def _local_time(folder: Path, storage: str, runs: int, workers: int) -> float:
    """Seconds for ``workers`` local worker processes to do the plan."""
    spec, study, points = _plan(folder, storage, runs)
    keys = enqueue(study, spec, points, phase="benchmark")
    start = time.perf_counter()
    work(spec, storage=storage, jobs=workers, idle_timeout_s=0.0, progress=False)
    elapsed = time.perf_counter() - start
    if len(finished_records(study, keys)) != runs:
        raise SystemExit("the local plan did not finish every run")
    return elapsed


def _slurm_time(folder: Path, storage: str, runs: int, workers: int) -> float:
    """Seconds for Slurm jobs (one a run, at most ``workers`` at once) to do the plan,
    queued and watched as ``surrogate run --launcher slurm`` does."""
    from dataclasses import replace

    from surrogate.identify._jobs import prepare_launch
    from surrogate.identify._worker import WorkerDispatcher

    spec, study, points = _plan(folder, storage, runs)
    spec = replace(spec, cluster=replace(spec.cluster, max_jobs=workers))
    launch = prepare_launch(
        "slurm", spec, storage, queue="verify", heartbeat_s=2, storage_patience_s=60.0
    )
    assert launch is not None
    dispatch = WorkerDispatcher(spec, storage, jobs=0, heartbeat_s=2, progress=False)
    dispatch.fleet = launch.fleet(study, patience=dispatch.patience, heartbeat_s=2, progress=False)
    start = time.perf_counter()
    with dispatch.fleet:
        done = dispatch(study, points, "benchmark")
    elapsed = time.perf_counter() - start
    if len(done) != runs or not all(record.ok for record in done.values()):
        raise SystemExit("the Slurm plan did not finish every run")
    return elapsed


def _slurm_main(args: argparse.Namespace) -> None:
    import contextlib
    import os
    import shutil
    import subprocess

    from tests.components import throwaway_slurm

    os.environ["FAKE_LSDYNA_SLEEP_S"] = str(args.cost)
    reached = (
        shutil.which("sbatch")
        and subprocess.run(["sinfo", "-h"], capture_output=True).returncode == 0
    )
    with contextlib.ExitStack() as stack, tempfile.TemporaryDirectory(prefix="bench-") as tmp:
        if not reached:
            os.environ["SLURM_CONF"] = stack.enter_context(throwaway_slurm())["SLURM_CONF"]
        server = stack.enter_context(throwaway_postgres())
        folder, (workers,) = Path(tmp), args.workers[:1]
        local = _local_time(folder / "local", create_database(server, "local"), args.runs, workers)
        slurm = _slurm_time(folder / "slurm", create_database(server, "slurm"), args.runs, workers)
    print(
        f"{args.runs}-run plan, LS-DYNA stand-in of {args.cost:g} s sleep a run (plus its own "
        f"start), {workers} at once, PostgreSQL"
    )
    print(f"{'workers':<22} {'wall time':>10} {'runs/hour':>10}")
    for label, seconds in (("local processes", local), ("Slurm jobs, one a run", slurm)):
        print(f"{label:<22} {seconds:>9.1f}s {3600 * args.runs / seconds:>10.0f}")
    overhead = workers * (slurm - local) / args.runs
    print(f"the scheduler's overhead per run: {overhead:.1f} s (job start, worker start, storage)")
    print(f"machine: {machine()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=None, help="runs of the plan (40; --slurm 12)")
    parser.add_argument("--cost", type=float, default=None, help="s per run (0.5; --slurm 2)")
    parser.add_argument("--workers", type=int, nargs="+", default=None, help="(1 2 4; --slurm 2)")
    parser.add_argument("--slurm", action="store_true", help="local workers beside Slurm jobs")
    args = parser.parse_args()
    if args.slurm:
        args.runs, args.cost = args.runs or 12, 2.0 if args.cost is None else args.cost
        args.workers = args.workers or [2]
        _slurm_main(args)
        return
    args.runs, args.cost = args.runs or 40, 0.5 if args.cost is None else args.cost
    args.workers = args.workers or [1, 2, 4]
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
