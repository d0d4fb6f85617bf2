"""Where the test suite's time goes: a sampling profile of every Python process it runs.

The suite's target is 10 minutes on 2 cores; this says what would have to get faster.
``py-spy`` (a dev dependency) samples the pytest processes, the processes they fork
(the diagnosis's refits) and the interpreters the tests start (the CLI, the workers), 25
times a second each, and this script sorts the samples into the kinds of work below
(first rule that matches wins) and by test file.

What a sample measures: a Python thread that is running or waiting for a core (py-spy
leaves out threads waiting on I/O or a lock, not threads waiting for the CPU). Where more
processes are runnable than there are cores, as when a test starts five workers at once,
their share is larger than their CPU time. ccx is not Python: its runs are not in the
profile (the CalculiX tests alone take 330 s of CPU, ``pytest -n 0 -m calculix``).

Run: .venv/bin/python benchmarks/suite_profile.py [--record suite.spy] [--read suite.spy]
     (--record runs the suite under py-spy, as root or with ptrace allowed; --read sorts a
     recorded file)
"""

from __future__ import annotations

import argparse
import collections
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks._machine import machine  # noqa: E402

RATE_HZ = 25

#: (kind of work, whether a sample's stack is of that kind), in order: the first that matches
KINDS: tuple[tuple[str, Callable[[str], bool]], ...] = (
    ("imports (an interpreter starting, a test module loading)", lambda s: "_find_and_load" in s),
    (
        "Optuna's TPE search on the surrogate (surrogate run)",
        lambda s: "identify/_loop.py" in s and "optuna/samplers" in s,
    ),
    (
        "model states and surrogate features",
        lambda s: "solvers/_state.py" in s or "calibration/_problem.py" in s,
    ),
    ("the built-in solver", lambda s: "surrogate/physics/" in s),
    (
        "GP fits and predictions (scikit-learn, surrogate.gp)",
        lambda s: "surrogate/gp/" in s or "sklearn/" in s,
    ),
    (
        "Optuna storages, SQLAlchemy, psycopg",
        lambda s: "sqlalchemy" in s or "optuna/" in s or "psycopg" in s,
    ),
    ("SciPy's optimisers (outside the GP fits)", lambda s: "scipy/optimize" in s),
)
TEST_FILE = re.compile(r"\((tests/[\w/]+\.py):\d+\)")
TEST_FUNCTION = re.compile(r"(test_\w+) \((tests/[\w/]+\.py):\d+\)")


def samples(path: Path) -> Iterator[tuple[str, int]]:
    """``(stack, count)`` of every line of a py-spy raw (collapsed-stack) file."""
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        stack, _, count = line.rpartition(" ")
        if count.isdigit():
            yield stack, int(count)


def kind_of(stack: str) -> str:
    return next((name for name, matches in KINDS if matches(stack)), "other")


def report(path: Path) -> str:
    kinds: collections.Counter[str] = collections.Counter()
    files: collections.Counter[str] = collections.Counter()
    tests: collections.Counter[str] = collections.Counter()
    for stack, count in samples(path):
        kinds[kind_of(stack)] += count
        match = TEST_FILE.search(stack)
        files[match.group(1) if match else "(none)"] += count
        test = TEST_FUNCTION.search(stack)
        if test:
            tests[f"{test.group(2)}::{test.group(1)}"] += count
    total = sum(kinds.values())
    if not total:
        raise SystemExit(f"{path}: no samples; is it a py-spy raw file (-f raw)?")
    lines = [f"{total} samples ({total / RATE_HZ:.0f} s of runnable Python at {RATE_HZ} Hz)"]
    lines += ["", "kind of work"]
    lines += [f"  {n / total:6.1%}  {name}" for name, n in kinds.most_common()]
    lines += [
        "",
        "test file on the stack (a forked child's is its test's; none: pytest itself and the "
        "interpreters the tests start, but for a test module run as a script)",
    ]
    lines += [f"  {n / total:6.1%}  {name}" for name, n in files.most_common(15)]
    lines += [
        "",
        "test function on the stack (its parameters together; the CLI it starts is not in it)",
    ]
    lines += [f"  {n / total:6.1%}  {name}" for name, n in tests.most_common(25)]
    return "\n".join(lines)


def record(out: Path) -> None:
    spy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or shutil.which("py-spy")
    if spy is None:
        raise SystemExit("py-spy not found; pip install -e '.[dev]' installs it")
    # scripts/test.sh's pytest options (the waiting tests in a process of their own)
    command = [sys.executable, "-m", "pytest", "-q", "-n", "auto", "--dist", "loadgroup"]
    command += ["-p", "no:cacheprovider", "--durations=40"]  # each test's wall time too
    start = time.perf_counter()
    spy_options = ["--subprocesses", "--nonblocking", "-r", str(RATE_HZ), "-f", "raw"]
    done = subprocess.run(
        [spy, "record", *spy_options, "-o", str(out), "--", *command],
        cwd=ROOT,
        check=False,
    )
    print(f"suite under py-spy: {time.perf_counter() - start:.0f} s, exit {done.returncode}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", type=Path, help="run the suite under py-spy into this file")
    parser.add_argument("--read", type=Path, help="sort a recorded file")
    args = parser.parse_args()
    if args.record is None and args.read is None:
        parser.error("give --record FILE, --read FILE or both")
    print(machine())
    if args.record is not None:
        record(args.record)
    print(report(args.read or args.record))


if __name__ == "__main__":
    main()
