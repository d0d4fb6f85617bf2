"""``[cluster]``: how a batch scheduler runs the study's worker jobs (``--launcher slurm``).

Every key is optional: with no ``[cluster]`` section the cluster's own defaults serve
(its default partition and time limit, one core a run, the memory it gives a core).
The keys are the scheduler's words where one is needed (``partition``, ``account``);
the launcher (:mod:`surrogate.cluster`) turns them into its own options.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from .._errors import InputDataError
from ._keys import keys

__all__ = ["ClusterSettings", "cluster_settings"]

_WORD = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.,+-]{0,127}$")  # a partition (or a,b), an account
_PREFIX = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")


@dataclass(frozen=True)
class ClusterSettings:
    """The validated ``[cluster]`` section (None: the cluster's default).

    ``cores`` and ``memory_mb`` are one run's (a job runs one run: ``cores`` tasks,
    ``$SLURM_NTASKS`` inside the job, ``memory_mb`` per node); ``time_limit_min`` is one
    run's wall time; ``max_jobs`` the most jobs queued or running at once;
    ``submit_options`` extra options of the submit command (``sbatch``), after ours;
    ``job_name_prefix`` starts every job's name; ``modules`` are loaded
    (``module load``) and ``setup`` lines run (a shell's) before the worker starts.
    """

    partition: str | None = None
    account: str | None = None
    time_limit_min: int | None = None
    cores: int = 1
    memory_mb: int | None = None
    max_jobs: int = 8
    submit_options: tuple[str, ...] = ()
    job_name_prefix: str = "surrogate-"
    modules: tuple[str, ...] = ()
    setup: tuple[str, ...] = ()


_KEYS = keys("cluster")  # declared with their meanings in ._keys


def cluster_settings(section: dict[str, Any], where: str) -> ClusterSettings:
    """``[cluster]`` of study file ``where``, or a one-line error naming key, value and fix."""
    for key in section:
        if key not in _KEYS:
            raise InputDataError(
                f"{where}: unknown key in [cluster] {key!r}; allowed: {', '.join(_KEYS)}"
            )
    default = ClusterSettings()
    return ClusterSettings(
        partition=_word(section, "partition", where),
        account=_word(section, "account", where),
        time_limit_min=_count(section, "time_limit_min", where, None),
        cores=_count(section, "cores", where, default.cores),
        memory_mb=_count(section, "memory_mb", where, None),
        max_jobs=_count(section, "max_jobs", where, default.max_jobs),
        submit_options=_options(section, where),
        job_name_prefix=_prefix(section, where),
        modules=tuple(_words(section, "modules", where)),
        setup=tuple(_lines(section, "setup", where)),
    )


def _word(section: dict[str, Any], key: str, where: str) -> str | None:
    value = section.get(key)
    if value is not None and not (isinstance(value, str) and _WORD.match(value)):
        raise InputDataError(
            f'{where}: cluster.{key} must be a name such as "compute" (letters, digits, '
            f"'_', '.', ',', '+', '-'), got {value!r}"
        )
    return value


def _count(section: dict[str, Any], key: str, where: str, default: int | None) -> Any:
    value = section.get(key, default)
    if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
        raise InputDataError(f"{where}: cluster.{key} must be a whole number ≥ 1, got {value!r}")
    return value


def _strings(section: dict[str, Any], key: str, where: str, example: str) -> list[str]:
    value = section.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise InputDataError(
            f"{where}: cluster.{key} must be a list of strings such as {example}, got {value!r}"
        )
    return value


def _words(section: dict[str, Any], key: str, where: str) -> list[str]:
    words = _strings(section, key, where, '["lsdyna/R13.1"]')
    for word in words:
        if not re.match(r"^[A-Za-z0-9][A-Za-z0-9_.+/-]*$", word):
            raise InputDataError(
                f"{where}: cluster.{key} names {word!r}, not a module name; "
                "put shell commands in cluster.setup"
            )
    return words


def _lines(section: dict[str, Any], key: str, where: str) -> list[str]:
    lines = _strings(section, key, where, '["source /shared/venv/bin/activate"]')
    for line in lines:
        if "\n" in line:
            raise InputDataError(f"{where}: cluster.{key} takes one command a string, got {line!r}")
    return lines


def _options(section: dict[str, Any], where: str) -> tuple[str, ...]:
    options = _strings(section, "submit_options", where, '["--qos=short"]')
    for option in options:
        if not option.startswith("-") or "\n" in option:
            raise InputDataError(
                f'{where}: cluster.submit_options takes options such as "--qos=short" '
                f"(one a string, each starting with '-'), got {option!r}"
            )
    return tuple(options)


def _prefix(section: dict[str, Any], where: str) -> str:
    prefix = section.get("job_name_prefix", ClusterSettings.job_name_prefix)
    if not isinstance(prefix, str) or not _PREFIX.match(prefix):
        raise InputDataError(
            f"{where}: cluster.job_name_prefix must be up to 32 letters, digits, '_', '.' "
            f"or '-', got {prefix!r}"
        )
    return prefix
