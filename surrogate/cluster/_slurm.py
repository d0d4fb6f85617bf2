"""Slurm's launcher: ``sbatch``, ``squeue``, ``scontrol``, ``scancel`` (and ``sacct`` if kept).

The batch script a job runs (:func:`batch_script`) carries our options as ``#SBATCH``
lines — one run's ``--ntasks`` (``$SLURM_NTASKS`` inside), ``--mem``, ``--time``,
``--partition``, ``--account``, and ``--signal=B:TERM@60``, so the worker (the batch
shell, ``exec``'d) gives its run back a minute before the time limit — and
``[cluster] submit_options`` go on ``sbatch``'s command line, where they override them.
The script comes on ``sbatch``'s standard input: nothing is written for it.

Pending reasons a job can never leave (:func:`never_starts`) are Slurm's job reason
codes (``squeue(1)``, JOB REASON CODES) of a request over a fixed limit; a drained
node, a busy partition or the account's running-job limit are waited for.
"""

from __future__ import annotations

import logging
import os
import re
import shlex
import shutil
import socket
import subprocess
from collections.abc import Sequence
from pathlib import Path

from .._errors import InputDataError
from ._launcher import ENDED, JOB_ID_VARIABLE, PENDING, RUNNING, JobRequest, JobState

__all__ = ["SlurmLauncher", "batch_script", "never_starts", "parse_squeue", "sbatch_directives"]

logger = logging.getLogger(__name__)

SIGNAL_BEFORE_LIMIT_S = 60
_TOOLS = ("sbatch", "squeue", "scontrol", "scancel", "sinfo")
_TIMEOUT_S = 60.0  # a controller that does not answer within this is an error
_FORMAT = "%i|%T|%r"  # job id, state, reason

_PENDING = {"PENDING", "REQUEUED", "REQUEUE_HOLD", "REQUEUE_FED", "RESV_DEL_HOLD", "SPECIAL_EXIT"}
_ENDED = {
    "BOOT_FAIL",
    "CANCELLED",
    "COMPLETED",
    "DEADLINE",
    "FAILED",
    "NODE_FAIL",
    "OUT_OF_MEMORY",
    "PREEMPTED",
    "REVOKED",
    "TIMEOUT",
}
_NEVER = {
    "PartitionTimeLimit": "its time limit is over the partition's; lower [cluster] "
    "time_limit_min or choose another partition",
    "PartitionNodeLimit": "it asks for more nodes than the partition allows; lower "
    "[cluster] cores or choose another partition",
    "InvalidAccount": "the account is not valid here; fix [cluster] account",
    "InvalidQOS": "the QOS is not valid here; fix the --qos of [cluster] submit_options",
    "BadConstraints": "its constraints can never be met; fix [cluster] submit_options",
    "DependencyNeverSatisfied": "it depends on a job that cannot succeed; fix [cluster] "
    "submit_options",
}
_NO_NODES = "Requested node configuration is not available"
_UP = {"idle", "alloc", "mix", "comp", "resv", "plnd", "npc"}  # sinfo's %t of a node at work
_PER_JOB = re.compile(r"Max\w*PerJob|MaxWallDuration")  # a per-job limit of the account or QOS
_BUDGET = re.compile(r"Grp\w*?(?<!Run)Minutes")  # CPU-minutes spent, not running jobs' minutes


def sbatch_directives(request: JobRequest) -> list[str]:
    """Our ``sbatch`` options for one job (one run's cores, memory and time)."""
    cluster = request.cluster
    options = [
        f"--job-name={request.name}",
        f"--output={request.log_dir / '%x-%j.out'}",
        f"--ntasks={cluster.cores}",
        f"--signal=B:TERM@{SIGNAL_BEFORE_LIMIT_S}",
    ]
    if cluster.partition:
        options.append(f"--partition={cluster.partition}")
    if cluster.account:
        options.append(f"--account={cluster.account}")
    if cluster.time_limit_min:
        options.append(f"--time={cluster.time_limit_min}")
    if cluster.memory_mb:
        options.append(f"--mem={cluster.memory_mb}M")
    return options


def batch_script(request: JobRequest) -> str:
    """The job's script: our directives, the modules and setup lines, the worker."""
    lines = ["#!/bin/bash", "# a worker job of surrogate: it runs one queued run and leaves"]
    lines += [f"#SBATCH {option}" for option in sbatch_directives(request)]
    lines += [f"module load {shlex.quote(module)}" for module in request.cluster.modules]
    lines += list(request.cluster.setup)
    lines.append(f'export {JOB_ID_VARIABLE}="$SLURM_JOB_ID"')
    lines.append("exec " + shlex.join(request.command))
    return "\n".join(lines) + "\n"


def never_starts(reason: str) -> str | None:
    """What to fix where a pending job's ``reason`` is one it can never leave, else None."""
    code = reason.split(",")[0].strip()
    if code in _NEVER:
        return _NEVER[code]
    if _PER_JOB.search(code):
        return (
            "it is over a per-job limit of the account or QOS; lower [cluster] cores, "
            "memory_mb or time_limit_min"
        )
    if _BUDGET.search(code):
        return "the account's CPU-time budget is spent; use another [cluster] account"
    return None


def parse_squeue(text: str) -> list[JobState]:
    """``squeue -h -o '%i|%T|%r'`` lines as job states (exit codes come from ``final``)."""
    jobs = []
    for line in text.splitlines():
        if line.count("|") < 2:
            continue
        job_id, state, reason = line.split("|", 2)
        state, reason = state.strip(), reason.strip()
        reason = "" if reason == "None" else reason
        phase = _phase(state)
        jobs.append(
            JobState(
                job_id.strip(),
                phase,
                state,
                reason,
                succeeded=state == "COMPLETED",
                never_starts=never_starts(reason) if phase == PENDING else None,
            )
        )
    return jobs


def _phase(state: str) -> str:
    return PENDING if state in _PENDING else ENDED if state in _ENDED else RUNNING


def _exit_code(text: str) -> int | None:
    """Slurm's ``ExitCode=status:signal`` as one number (negative: the signal)."""
    match = re.match(r"^(\d+):(\d+)$", text.strip())
    if match is None:
        return None
    status, signal_number = int(match[1]), int(match[2])
    return -signal_number if signal_number else status


def _ended_state(job_id: str, state: str, reason: str, exit_text: str) -> JobState:
    state = state.split()[0] if state else "UNKNOWN"
    code = _exit_code(exit_text)
    return JobState(
        job_id,
        _phase(state),
        state,
        "" if reason == "None" else reason,
        exit_code=code,
        succeeded=state == "COMPLETED" and code == 0,
    )


class SlurmLauncher:
    """The launcher contract (:mod:`surrogate.cluster._launcher`) on Slurm's commands."""

    name = "slurm"

    def check(self, request: JobRequest) -> None:
        missing = [tool for tool in _TOOLS if shutil.which(tool) is None]
        if missing:
            raise InputDataError(
                f"--launcher slurm: {', '.join(missing)} not on PATH; run the planner where "
                "Slurm's commands work (a login node, or `module load slurm`)"
            )
        done = self._run(
            ["sbatch", "--test-only", *request.cluster.submit_options],
            script=batch_script(request),
            check=False,
        )
        if done.returncode != 0 and _NO_NODES in done.stderr and not self._nodes_up(request):
            # every node of the partition drained or down: a maintenance the jobs wait for
            # (Slurm answers for those as for a request no node could ever meet)
            logger.warning(
                "every node of the jobs' partition is drained or down now; they wait for them"
            )
        elif done.returncode != 0:
            raise InputDataError(
                f"sbatch refuses the jobs of [cluster] ({_first_line(done.stderr)}); fix "
                "partition, account, cores, memory_mb, time_limit_min or submit_options"
            )

    def _nodes_up(self, request: JobRequest) -> bool:
        """Whether a node of the jobs' partition is up (idle, busy, completing, reserved)."""
        partition = request.cluster.partition
        where = ["-p", partition] if partition else []
        states = self._run(["sinfo", "-h", "-o", "%t", *where], check=False).stdout.split()
        return any(state.rstrip("*~#!%$@^-") in _UP for state in states)

    def runs_here(self, request: JobRequest) -> bool:
        partition = request.cluster.partition
        where = ["-p", partition] if partition else []
        listed = self._run(["sinfo", "-h", "-o", "%N", *where]).stdout.split()
        nodes = set()
        for expression in listed:
            nodes |= set(self._run(["scontrol", "show", "hostnames", expression]).stdout.split())
        return bool(nodes) and nodes <= _this_host()

    def submit(self, request: JobRequest) -> str:
        done = self._run(
            ["sbatch", "--parsable", *request.cluster.submit_options],
            script=batch_script(request),
            environment=dict(request.environment),
            check=False,
        )
        if done.returncode != 0:
            raise InputDataError(
                f"sbatch refused a worker job ({_first_line(done.stderr)}); fix [cluster]"
            )
        return done.stdout.strip().split(";")[0]

    def jobs(self, name: str) -> list[JobState]:
        listed = self._run(
            ["squeue", "--me", "-h", "--states=all", f"--name={name}", "-o", _FORMAT]
        )
        return parse_squeue(listed.stdout)

    def final(self, job_id: str) -> JobState | None:
        shown = self._run(["scontrol", "show", "job", "-o", job_id], check=False)
        if shown.returncode == 0 and shown.stdout.strip():
            fields = dict(re.findall(r"(\w+)=(\S*)", shown.stdout))
            return _ended_state(
                job_id,
                fields.get("JobState", ""),
                fields.get("Reason", ""),
                fields.get("ExitCode", ""),
            )
        if shutil.which("sacct") is None:
            return None
        kept = self._run(
            ["sacct", "-n", "-X", "-P", "-j", job_id, "-o", "State,ExitCode"], check=False
        )
        rows = [line.split("|") for line in kept.stdout.splitlines() if line.count("|") == 1]
        if kept.returncode != 0 or not rows:
            return None  # forgotten, and no accounting (or not there either)
        return _ended_state(job_id, rows[0][0], "", rows[0][1])

    def cancel(self, job_ids: Sequence[str]) -> None:
        if job_ids:
            self._run(["scancel", *job_ids], check=False)

    def log_file(self, request: JobRequest, job_id: str) -> Path:
        return request.log_dir / f"{request.name}-{job_id}.out"

    @staticmethod
    def _run(
        args: list[str],
        *,
        script: str | None = None,
        environment: dict[str, str] | None = None,
        check: bool = True,
    ) -> subprocess.CompletedProcess[str]:
        try:
            done = subprocess.run(
                args,
                input=script,
                capture_output=True,
                text=True,
                timeout=_TIMEOUT_S,
                env={**os.environ, **(environment or {})},
            )
        except FileNotFoundError:
            raise InputDataError(f"--launcher slurm: {args[0]} is not on PATH") from None
        except subprocess.TimeoutExpired:
            raise InputDataError(
                f"{args[0]} did not answer within {_TIMEOUT_S:g} s; is slurmctld up?"
            ) from None
        if check and done.returncode != 0:
            raise InputDataError(f"{shlex.join(args)} failed: {_first_line(done.stderr)}")
        return done


def _first_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else "no message"


def _this_host() -> set[str]:
    name = socket.gethostname()
    return {name, name.split(".")[0], socket.getfqdn(), "localhost"}
