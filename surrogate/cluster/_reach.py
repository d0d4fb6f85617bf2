"""Whether jobs on the cluster's nodes can reach the study's storage and its folder.

A worker job runs on a node, not here: it must open the storage and read the study
file (and share the result cache beside it). What only this machine reaches is refused
unless every node is this machine (a single-node cluster, as in the tests): a server
on 127.0.0.1, ``localhost`` or a local socket, a journal or a study folder on a local
disk. SQLite and an in-memory database are refused everywhere: SQLite hands one queued
run to two workers, and an in-memory database exists in one process only. A file
system we cannot name (FUSE, an unknown one) is given the benefit of the doubt.
"""

from __future__ import annotations

from pathlib import Path

from .._errors import InputDataError
from ..storage._storage import in_memory_storage, journal_path, normalise_storage_url, storage_kind

__all__ = ["LOCAL_FILE_SYSTEMS", "check_reachable", "file_system", "unreachable_reason"]

LOCAL_FILE_SYSTEMS = frozenset(
    {"ext2", "ext3", "ext4", "xfs", "btrfs", "tmpfs", "overlay", "f2fs", "vfat", "zfs", "ramfs"}
)
_LOOPBACK = ("localhost", "127.", "::1", "[::1]")


def unreachable_reason(
    storage_url: str, *, storage_fs: str | None, study_fs: str | None, runs_here: bool
) -> str | None:
    """Why jobs cannot use ``storage_url`` (and the study folder), else None.

    ``storage_fs``/``study_fs`` are the file-system types of the journal's folder and
    the study's (None: not a file, or not known); ``runs_here`` whether every node is
    this machine.
    """
    kind = storage_kind(storage_url)
    if in_memory_storage(storage_url):
        return "an in-memory SQLite database exists only inside this process"
    if kind == "sqlite":
        return "SQLite hands the same queued run to two workers"
    if runs_here:
        return None
    host = "" if kind == "journal" else _host(storage_url)
    if kind != "journal" and (not host or host.startswith(_LOOPBACK)):
        return "the database is on this machine's loopback address (or socket)"
    if storage_fs in LOCAL_FILE_SYSTEMS:
        return f"the journal is on a local disk ({storage_fs})"
    if study_fs in LOCAL_FILE_SYSTEMS:
        return f"the study folder is on a local disk ({study_fs}); the jobs read the study file"
    return None


def check_reachable(storage_url: str, study_dir: Path, *, runs_here: bool) -> None:
    """Refuse, in one line, a storage or study folder the cluster's jobs cannot reach."""
    journal = journal_path(storage_url)
    reason = unreachable_reason(
        storage_url,
        storage_fs=None if journal is None else file_system(journal.parent),
        study_fs=file_system(study_dir),
        runs_here=runs_here,
    )
    if reason is not None:
        raise InputDataError(
            f"--storage {storage_url}: the cluster's jobs cannot use it ({reason}); use "
            "postgresql://user@dbhost/db (a host the nodes reach) or journal:///shared/"
            "study.log on a file system every node mounts, with the study folder there too"
        )


def _host(url: str) -> str:
    from sqlalchemy.engine import make_url

    return (make_url(normalise_storage_url(url)).host or "").lower()


def file_system(path: Path) -> str | None:
    """The type of the file system ``path`` is on (Linux ``/proc/mounts``), else None."""
    try:
        mounts = Path("/proc/mounts").read_text().splitlines()
    except OSError:
        return None
    target, best = str(Path(path).resolve()), None
    for line in mounts:
        fields = line.split()
        if len(fields) < 3:
            continue
        point = fields[1].replace("\\040", " ")
        inside = target == point or target.startswith(point.rstrip("/") + "/")
        if inside and (best is None or len(point) >= len(best[0])):
            best = (point, fields[2])
    return None if best is None else best[1]
