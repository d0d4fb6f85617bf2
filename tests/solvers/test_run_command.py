"""An external solver dies with its caller, however the caller dies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from surrogate._errors import SolverError
from surrogate.solvers._base import SolverStalled, _die_with_parent, run_command

CALLER = """
import sys
from pathlib import Path
from surrogate.solvers._base import run_command
run_command(["sleep", "300"], cwd=Path(sys.argv[1]), timeout_s=600)
"""


def _children(pid):
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux: /proc and pdeathsig")
def test_a_sigkilled_caller_takes_its_solver_along(tmp_path):
    caller = subprocess.Popen([sys.executable, "-c", CALLER, str(tmp_path)])
    deadline = time.monotonic() + 60
    while not (children := _children(caller.pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert children, "the caller never started its solver"
    caller.send_signal(signal.SIGKILL)
    caller.wait(timeout=10)
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in children), "the solver outlived its SIGKILLed caller"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux: /proc and pdeathsig")
def test_a_solver_whose_caller_died_before_its_death_signal_was_set_does_not_start(tmp_path):
    """The window between the fork and ``setpriv``'s ``prctl``: where the solver's parent
    is no longer the process that started it, the program does not run."""
    prefix = _die_with_parent(caller=os.getpid() + 1)  # not the parent of what it starts
    assert prefix, "setpriv --pdeathsig does not work here"
    done = subprocess.run([*prefix, "touch", str(tmp_path / "ran")], check=False)
    assert done.returncode == 137 and not (tmp_path / "ran").exists()
    assert subprocess.run([*_die_with_parent(), "true"], check=False).returncode == 0


def test_a_missing_program_or_a_timeout_is_a_solver_error(tmp_path):
    with pytest.raises(SolverError, match="no-such-solver: command not found"):
        run_command(["no-such-solver"], cwd=tmp_path, timeout_s=5)
    with pytest.raises(SolverError, match=r"\./missing: command not found"):
        run_command(["./missing"], cwd=tmp_path, timeout_s=5)
    with pytest.raises(SolverError, match=r"sleep did not finish within 0.2 s \(timeout_s\)"):
        run_command(["sleep", "5"], cwd=tmp_path, timeout_s=0.2)


def test_a_program_relative_to_the_work_folder_runs(tmp_path):
    script = tmp_path / "solver.sh"
    script.write_text("#!/bin/sh\necho solved in $(pwd)\n")
    script.chmod(0o755)
    done = run_command(["./solver.sh"], cwd=tmp_path, timeout_s=10)
    assert done.returncode == 0 and done.stdout.strip() == f"solved in {tmp_path}"
    assert os.path.exists(script)


def test_a_stalled_program_is_stopped_with_its_reason_children_and_all(tmp_path):
    """``stalled`` reads the program's own progress (here: a file its child writes) and
    stops a run that will not finish long before its timeout; a wrapper script's child
    dies with it (its progress stops growing)."""
    script = tmp_path / "solver.sh"
    script.write_text("#!/bin/sh\n(while true; do echo x >> progress; sleep 0.05; done) &\nwait\n")
    script.chmod(0o755)
    progress = tmp_path / "progress"

    def stalled():
        lines = len(progress.read_text().split()) if progress.exists() else 0
        return f"{lines} lines of progress" if lines >= 5 else None

    start = time.monotonic()
    with pytest.raises(SolverStalled, match=r"^\d+ lines of progress$"):
        run_command(["./solver.sh"], cwd=tmp_path, timeout_s=60, stalled=stalled)
    assert time.monotonic() - start < 30
    written = progress.read_text()
    time.sleep(0.5)
    assert progress.read_text() == written, "the wrapper's child outlived the stall"


def test_a_program_that_finishes_is_not_stalled(tmp_path):
    asked = []

    def stalled():
        asked.append(1)
        return None

    done = run_command(
        ["sh", "-c", "sleep 1.5; echo done"], cwd=tmp_path, timeout_s=30, stalled=stalled
    )
    assert done.returncode == 0 and done.stdout == "done\n" and asked
