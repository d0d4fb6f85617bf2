"""Real components the system tests need (PostgreSQL, Chromium): find or give up.

In CI (``CI=true``) a missing component fails the test; elsewhere it skips with
the reason. ``scripts/system-packages.sh`` installs both when run as root.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

INSTALL = "run scripts/system-packages.sh as root (Debian: apt-get install postgresql chromium)"
SLURM_INSTALL = "run scripts/system-packages.sh as root (Debian: apt-get install slurm-wlm munge)"


def missing(reason: str) -> None:
    """Fail in CI, skip elsewhere."""
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason} (CI=true: a missing component is a failure)", pytrace=False)
    pytest.skip(reason)


def postgres_bin_dir() -> Path | None:
    """A folder with initdb, pg_ctl and postgres (PATH first, then Debian's layout)."""
    candidates = []
    if shutil.which("initdb"):
        candidates.append(Path(shutil.which("initdb")).resolve().parent)
    candidates += [
        Path(d)
        for d in sorted(
            glob.glob("/usr/lib/postgresql/*/bin"),
            key=lambda d: int(Path(d).parent.name) if Path(d).parent.name.isdigit() else 0,
            reverse=True,
        )
    ]
    for folder in candidates:
        if all(os.access(folder / name, os.X_OK) for name in ("initdb", "pg_ctl", "postgres")):
            return folder
    return None


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if os.access("/usr/bin/chromium", os.X_OK) else None


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class ComponentMissing(RuntimeError):
    """A real component a test or benchmark needs is not installed."""


def _as_server_user(command: list[str]) -> list[str]:
    """postgres refuses to run as root: run it as the ``postgres`` user then."""
    return ["runuser", "-u", "postgres", "--", *command] if os.geteuid() == 0 else command


@contextlib.contextmanager
def throwaway_postgres() -> Iterator[str]:
    """Start a PostgreSQL server in a temporary folder; yield its URL (no database).

    It listens on 127.0.0.1 only, on a free port, with trust authentication for
    the user ``surrogate``; it is stopped and its folder deleted afterwards.
    """
    bindir = postgres_bin_dir()
    if bindir is None:
        raise ComponentMissing(f"PostgreSQL (initdb, pg_ctl, postgres) not found; {INSTALL}")
    folder = Path(tempfile.mkdtemp(prefix="surrogate-pg-"))
    if os.geteuid() == 0:
        if shutil.which("runuser") is None:
            raise ComponentMissing("running as root and runuser is missing")
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            raise ComponentMissing("running as root and there is no 'postgres' user") from None
        os.chown(folder, user.pw_uid, user.pw_gid)
    data, port = folder / "data", free_port()

    def run(*args: str) -> None:
        command = _as_server_user([str(bindir / args[0]), *args[1:]])
        subprocess.run(command, check=True, capture_output=True, text=True, timeout=120, cwd=folder)

    try:
        run("initdb", "-D", str(data), "-U", "surrogate", "-A", "trust", "-E", "UTF8", "--no-sync")
        options = (
            f"-c listen_addresses=127.0.0.1 -p {port} -k {folder} "
            "-c fsync=off -c synchronous_commit=off -c full_page_writes=off"
        )

        def start() -> None:
            run("pg_ctl", "-D", str(data), "-o", options, "-l", str(folder / "log"), "-w", "start")

        start()
        url = f"postgresql://surrogate@127.0.0.1:{port}"
        _CONTROLS[url] = {
            "start": start,
            "stop": lambda: run("pg_ctl", "-D", str(data), "-w", "stop"),
        }
        yield url
    finally:
        _CONTROLS.pop(f"postgresql://surrogate@127.0.0.1:{port}", None)
        if (data / "postmaster.pid").exists():
            subprocess.run(
                _as_server_user(
                    [str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"]
                ),
                capture_output=True,
                timeout=60,
            )
        shutil.rmtree(folder, ignore_errors=True)


_CONTROLS: dict[str, dict[str, Callable[[], None]]] = {}


def postgres_control(server_url: str, action: str) -> None:
    """``stop`` (fast shutdown: sessions are cut) or ``start`` again a server that
    :func:`throwaway_postgres` started in this process."""
    _CONTROLS[server_url][action]()


def create_database(server_url: str, name: str) -> str:
    """A new empty database on ``server_url``; returns its URL."""
    import psycopg

    with psycopg.connect(f"{server_url}/postgres", autocommit=True) as connection:
        connection.execute(f'CREATE DATABASE "{name}"')
    return f"{server_url}/{name}"


_SLURM_DAEMONS = ("slurmctld", "slurmd", "munged", "mungekey")


@contextlib.contextmanager
def throwaway_slurm() -> Iterator[dict[str, str]]:
    """Start a real single-node Slurm in a temporary folder; yield ``SLURM_CONF``, the node.

    Debian's ``slurm-wlm`` and ``munge``: a munged of its own (its own key, socket and
    pid in the folder), a slurmctld with this host as controller and a slurmd with this
    host as a node of all its CPUs, on free ports, ``proctrack/linuxproc`` and
    ``task/none`` (no cgroups), state, spool and logs in the folder (as
    /work/shared/slurm-single-node.sh). Partitions: ``debug`` (the default, no time
    limit) and ``short`` (at most 1 minute). Needs root (slurmd runs as root). The
    daemons are stopped by their pids afterwards and the folder deleted.
    """
    if os.geteuid() != 0:
        raise ComponentMissing("a single-node Slurm needs root (slurmd runs as root)")
    tools = {name: shutil.which(name) or f"/usr/sbin/{name}" for name in _SLURM_DAEMONS}
    missing_tools = [n for n, p in tools.items() if not os.access(p, os.X_OK)]
    missing_tools += [n for n in ("sbatch", "squeue", "scontrol", "sinfo") if not shutil.which(n)]
    if missing_tools:
        raise ComponentMissing(
            f"Slurm or munge not installed ({', '.join(missing_tools)}); {SLURM_INSTALL}"
        )
    try:
        munge = pwd.getpwnam("munge")
    except KeyError:
        raise ComponentMissing(f"there is no 'munge' user; {SLURM_INSTALL}") from None
    folder = Path(tempfile.mkdtemp(prefix="surrogate-slurm-"))
    folder.chmod(0o755)
    for sub in ("spool", "state", "log", "munge"):
        (folder / sub).mkdir()
    os.chown(folder / "munge", munge.pw_uid, munge.pw_gid)
    (folder / "munge").chmod(0o755)  # munged: its socket's folder open to all
    conf, node = folder / "slurm.conf", socket.gethostname().split(".")[0]
    pids = [folder / "slurmd.pid", folder / "slurmctld.pid", folder / "munge" / "munged.pid"]
    try:
        key = folder / "munge" / "munge.key"
        subprocess.run([tools["mungekey"], "-c", "-k", str(key)], check=True, capture_output=True)
        os.chown(key, munge.pw_uid, munge.pw_gid)
        conf.write_text(_slurm_conf(folder, node))
        subprocess.run(
            [
                "runuser",
                "-u",
                "munge",
                "--",
                tools["munged"],
                f"--key-file={key}",
                f"--socket={folder / 'munge' / 'munge.sock'}",
                f"--pid-file={pids[2]}",
                f"--seed-file={folder / 'munge' / 'seed'}",
            ],
            check=True,
            capture_output=True,
            text=True,
            timeout=60,
        )
        for daemon in ("slurmctld", "slurmd"):
            subprocess.run(
                [tools[daemon], "-f", str(conf)],
                check=True,
                capture_output=True,
                text=True,
                timeout=60,
            )
        environment = {"SLURM_CONF": str(conf)}
        _wait_idle(environment)
        yield {**environment, "node": node, "folder": str(folder)}
    finally:
        _stop_by_pid(pids)
        shutil.rmtree(folder, ignore_errors=True)


def _slurm_conf(folder: Path, node: str) -> str:
    """The single-node cluster of :func:`throwaway_slurm` (KillWait 5 s: a job cancelled or
    over its limit gets SIGKILL 5 s after SIGTERM, not 30; the scheduler looks at pending
    jobs every 2 s, not 60, so a job held by a drained node starts soon after a resume)."""
    port = free_port()
    lines = [
        "ClusterName=surrogate-test",
        f"SlurmctldHost={node}",
        f"SlurmctldPort={port}",
        f"SlurmdPort={free_port()}",
        "AuthType=auth/munge",
        f"AuthInfo=socket={folder / 'munge' / 'munge.sock'}",
        "ProctrackType=proctrack/linuxproc",
        "TaskPlugin=task/none",
        "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_CPU_Memory",
        "DefMemPerCPU=1000",
        "ReturnToService=2",
        "KillWait=5",
        "SchedulerParameters=sched_interval=2,bf_interval=2",
        f"SlurmctldPidFile={folder / 'slurmctld.pid'}",
        f"SlurmdPidFile={folder / 'slurmd.pid'}",
        f"SlurmdSpoolDir={folder / 'spool'}",
        f"StateSaveLocation={folder / 'state'}",
        f"SlurmctldLogFile={folder / 'log' / 'ctld.log'}",
        f"SlurmdLogFile={folder / 'log' / 'slurmd.log'}",
        "JobCompType=jobcomp/filetxt",
        f"JobCompLoc={folder / 'log' / 'jobcomp.txt'}",
        "SlurmUser=root",
        "MpiDefault=none",
        f"NodeName={node} CPUs={os.cpu_count()} RealMemory=4000 State=UNKNOWN",
        f"PartitionName=debug Nodes={node} Default=YES MaxTime=INFINITE State=UP",
        f"PartitionName=short Nodes={node} MaxTime=1 State=UP",
    ]
    return "\n".join(lines) + "\n"


def _wait_idle(environment: dict[str, str], timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done = subprocess.run(
            ["sinfo", "-h", "-o", "%t"],
            capture_output=True,
            text=True,
            env={**os.environ, **environment},
        )
        if "idle" in done.stdout:
            return
        time.sleep(0.5)
    raise ComponentMissing(f"Slurm's node did not become idle within {timeout_s:g} s")


def _stop_by_pid(pid_files: list[Path], timeout_s: float = 30.0) -> None:
    """SIGTERM each daemon of a pid file, then wait for it to end (SIGKILL at the timeout)."""
    pids = []
    for path in pid_files:
        try:
            pids.append(int(path.read_text().split()[0]))
        except (OSError, ValueError, IndexError):
            continue
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, 15)
    deadline = time.monotonic() + timeout_s
    for pid in pids:
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        if _alive(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, 9)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


class Dashboard:
    """``surrogate dashboard STUDY [--storage URL] --port P`` in a subprocess, and its
    JSON API (a context manager: the server is stopped at the end)."""

    def __init__(self, study: str | os.PathLike[str], storage: str | None = None) -> None:
        self.port = free_port()
        where = ["--storage", storage] if storage else []
        self.server = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "surrogate",
                "dashboard",
                str(study),
                *where,
                "--port",
                str(self.port),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def __enter__(self) -> Dashboard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.terminate()
        self.server.wait(timeout=10)

    def studies(self) -> list[dict]:
        """The study summaries, once the server answers: up to 180 s while it runs (its
        start is imports, slow on a loaded machine; 15 s failed with two suites on two
        cores), at once with its stderr if it ended."""
        deadline = time.monotonic() + 180.0
        while time.monotonic() < deadline:
            try:
                return self.get("/api/studies")["study_summaries"]
            except OSError:
                if self.server.poll() is not None:  # it ended: no point waiting
                    break
                time.sleep(0.25)
        ended = self.server.poll()
        raise AssertionError(
            f"the dashboard did not answer on 127.0.0.1 (exit code {ended}; "
            f"{self.server.stderr.read() if ended is not None else 'still running'})"
        )

    def detail(self, study_name: str) -> dict:
        """The dashboard's view of one study (trials, figures, note)."""
        study_id = next(s["study_id"] for s in self.studies() if s["study_name"] == study_name)
        return self.get(f"/api/studies/{study_id}?after=0")

    def get(self, path: str) -> dict:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}{path}", timeout=5) as r:
            return json.load(r)
