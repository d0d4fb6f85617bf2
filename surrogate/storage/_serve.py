"""``dashboard``: optuna-dashboard on a study's storage, on 127.0.0.1 only.

It serves the files attached to the study's studies (the report of ``surrogate
report``) from the study's artifact folder (:func:`._dashboard.artifact_folder`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from .._errors import InputDataError
from ..effects import check_effects
from ..study._spec import StudySpec, load_study
from ._dashboard import artifact_folder
from ._storage import open_storage, unstored

__all__ = ["dashboard"]

HOST = "127.0.0.1"  # never 0.0.0.0: reach it from elsewhere through an SSH tunnel


def dashboard(
    study: str | Path | StudySpec,
    *,
    storage: str | None = None,
    port: int = 8080,
    plugins: Sequence[str] = (),
) -> None:
    """Serve optuna-dashboard for the study's storage until interrupted (``plugins``:
    modules of effects the study's ``[model] effects`` name)."""
    spec = study if isinstance(study, StudySpec) else load_study(study)
    check_effects(spec.effects, plugins)
    if not 1024 <= port <= 65535:
        raise InputDataError(f"--port must be in [1024, 65535], got {port}")
    url = storage or spec.default_storage()
    if unstored(url, "the dashboard") is not None:  # nothing is created where none is yet
        raise InputDataError(f"no storage at {url} yet; run `surrogate run {spec.path}` first")
    opened = open_storage(url)  # a journal file works too
    try:
        from optuna_dashboard import run_server
    except ImportError:
        raise InputDataError(
            "optuna-dashboard is not installed; pip install 'webbing-surrogate[dashboard]'"
        ) from None
    from optuna.artifacts import FileSystemArtifactStore

    files = artifact_folder(spec.directory, spec.name)
    files.mkdir(parents=True, exist_ok=True)
    print(f"optuna-dashboard for {url} on http://{HOST}:{port}/ (Ctrl-C to stop)", flush=True)
    run_server(opened, host=HOST, port=port, artifact_store=FileSystemArtifactStore(files))
