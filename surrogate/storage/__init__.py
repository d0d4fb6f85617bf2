"""Optuna at the edge: storages, the one converter to distributions, the dashboard.

- :mod:`._storage`: storage URLs (SQLite, journal, PostgreSQL), heartbeats for many
  workers, one-line storage errors;
- :mod:`._optuna`: a parameter space as Optuna distributions, and quiet Optuna;
- :mod:`._dashboard`: figures, notes and files (artifacts) a study shows in optuna-dashboard;
- :mod:`._serve`: ``dashboard`` (optuna-dashboard on 127.0.0.1 only).
"""

from ._optuna import distributions, quiet_optuna
from ._storage import StorageError, check_workers, open_storage, storage_error_message

__all__ = [
    "StorageError",
    "check_workers",
    "distributions",
    "open_storage",
    "quiet_optuna",
    "storage_error_message",
]
