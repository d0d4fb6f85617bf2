"""A result cache keyed by a hash of the solver inputs.

One JSON file per run (``<hash>.json``), written atomically, so an interrupted
batch resumes where it stopped and an identical point is never solved twice.
The hash covers the parameters, the rig, effects, conditions and the solver's
name and version.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from .._io import atomic_write_text
from ._base import run_identity

__all__ = ["ResultCache", "canonical_json", "input_hash"]


def canonical_json(payload: Any) -> str:
    """Key-sorted, whitespace-free JSON, floats as their shortest repr."""
    return json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)


def input_hash(inputs: dict[str, Any]) -> str:
    """SHA-256 (hex, 24 characters) of the canonical JSON of a run's identity: the solver
    inputs less the settings that only say how to run (program, timeout, threads, work
    folders: :func:`surrogate.solvers._base.run_identity`)."""
    identity = run_identity(inputs)
    return hashlib.sha256(canonical_json(identity).encode("utf-8")).hexdigest()[:24]


class ResultCache:
    """A directory of ``<hash>.json`` files: ``{"inputs": …, "result": …}``."""

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.directory = Path(directory)

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored result, or None (also for an unreadable entry, which is redone)."""
        try:
            entry = json.loads(self._path(key).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return None
        if not isinstance(entry, dict) or input_hash(entry.get("inputs", {})) != key:
            return None
        result = entry.get("result")
        return result if isinstance(result, dict) else None

    def put(self, key: str, inputs: dict[str, Any], result: dict[str, Any]) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self._path(key), json.dumps({"inputs": inputs, "result": result}))

    def __contains__(self, key: str) -> bool:
        return self.get(key) is not None

    def hits(self, keys: list[str]) -> tuple[dict[int, dict[str, Any]], list[int]]:
        """The stored results of ``keys`` by position, and the positions not stored (to
        solve)."""
        results: dict[int, dict[str, Any]] = {}
        todo = []
        for i, key in enumerate(keys):
            hit = self.get(key)
            if hit is None:
                todo.append(i)
            else:
                results[i] = hit
        return results, todo
