"""A real single-node Slurm for the session (as the throwaway PostgreSQL), and studies
whose full solver runs inside the jobs through ``srun``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.components import ComponentMissing, missing, throwaway_slurm
from tests.workers.conftest import postgres_server, postgres_url  # noqa: F401 (fixtures)

FIXTURES = Path(__file__).resolve().parents[1] / "solvers" / "fixtures"
TEMPLATE = FIXTURES / "bending_template.k"
FAKE_LSDYNA = FIXTURES / "fake_lsdyna.py"


@pytest.fixture(scope="session")
def slurm():
    """``{"SLURM_CONF", "node", "folder"}`` of a single-node Slurm started for the session
    (``SLURM_CONF`` is set in this process meanwhile); stopped by pid afterwards."""
    try:
        cluster = throwaway_slurm()
        found = cluster.__enter__()
    except ComponentMissing as error:
        missing(str(error))
    except subprocess.CalledProcessError as error:
        pytest.fail(f"Slurm did not start: {error.stderr or error.stdout}", pytrace=False)
    before = os.environ.get("SLURM_CONF")
    os.environ["SLURM_CONF"] = found["SLURM_CONF"]
    try:
        yield found
    finally:
        if before is None:
            os.environ.pop("SLURM_CONF", None)
        else:
            os.environ["SLURM_CONF"] = before
        cluster.__exit__(None, None, None)


@pytest.fixture
def clean_queue(slurm):
    """Every test leaves the queue empty: what is still queued or running is cancelled
    afterwards (the test's own assertions say whether anything was)."""
    yield slurm
    listed = subprocess.run(["squeue", "-h", "-o", "%i"], capture_output=True, text=True)
    if listed.stdout.split():
        subprocess.run(["scancel", *listed.stdout.split()], capture_output=True)
    subprocess.run(
        ["scontrol", "update", f"nodename={slurm['node']}", "state=resume"], capture_output=True
    )


def lsdyna_study(folder: Path, *, name: str = "belt", cluster: str = "max_jobs = 2\n") -> Path:
    """A study whose full solver is the LS-DYNA stand-in (NOT LS-DYNA), run as LS-DYNA MPP
    is on a cluster: ``srun`` in the job's allocation (``$SLURM_NTASKS`` tasks)."""
    command = ["srun", "--quiet", sys.executable, str(FAKE_LSDYNA)]
    path = folder / f"{name}.toml"
    path.write_text(
        f'[study]\nname = "{name}"\n[targets]\nf60_n = 9.958\n'
        f'[solver]\nkind = "lsdyna"\ntemplate = "{TEMPLATE}"\ncommand = {json.dumps(command)}\n'
        f"[budget]\nsurrogate_trials = 100\n[cluster]\n{cluster}"
    )
    return path
