"""What a study shows in optuna-dashboard: figures, a note, and files (artifacts).

Plotting libraries are imported here, where they are used. Files such as the
report of ``surrogate report`` are artifacts of the study: their content lives in
a folder next to the study file (:func:`artifact_folder`), which ``surrogate
dashboard`` serves.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna

__all__ = ["artifact_folder", "attach_file", "attach_run_report", "verified_curves_figure"]


def attach_run_report(
    study: optuna.Study,
    *,
    target_n: float,
    tolerance: float,
    records: Sequence[Any],
    chosen_number: int | None,
    note: str,
) -> bool:
    """Attach the verified curves against the target and a note to ``study``.

    Returns False (and warns) when plotly or optuna-dashboard is not installed.
    """
    try:
        from optuna_dashboard import save_note, save_plotly_graph_object

        figure = verified_curves_figure(
            records, target_n=target_n, tolerance=tolerance, chosen_number=chosen_number
        )
    except ImportError as error:  # optional: pip install .[plots,dashboard]
        warnings.warn(f"dashboard report skipped ({error.name} is not installed)", stacklevel=2)
        return False
    save_plotly_graph_object(study, figure, graph_object_id="verified-curves")
    save_note(study, note)
    return True


def verified_curves_figure(
    records: Sequence[Any], *, target_n: float, tolerance: float, chosen_number: int | None
) -> Any:
    """A plotly figure of every successful verification's curve (``records``:
    :class:`~surrogate.identify._verify.Verification`), the chosen one highlighted,
    against the target F60 ± tolerance. Raises ImportError without plotly."""
    import plotly.graph_objects as go

    figure = go.Figure()
    for record in sorted(records, key=lambda r: r.number or 0):
        if not record.ok:
            continue
        chosen = record.number == chosen_number
        figure.add_trace(
            go.Scatter(
                x=record.angle_deg,
                y=record.force_n,
                mode="lines",
                name=f"trial {record.number}" + (" (chosen)" if chosen else ""),
                line={"width": 3 if chosen else 1, "color": "crimson" if chosen else None},
                opacity=1.0 if chosen else 0.45,
            )
        )
    figure.add_trace(
        go.Scatter(
            x=[60.0, 60.0],
            y=[target_n * (1 - tolerance), target_n * (1 + tolerance)],
            mode="lines+markers",
            name=f"target F60 = {target_n:.4g} N ± {100 * tolerance:g} %",
            line={"color": "black", "width": 6},
        )
    )
    figure.update_layout(
        title="Verified full-solver curves against the target",
        xaxis_title="fixture rotation [deg]",
        yaxis_title="probe force [N]",
    )
    return figure


def artifact_folder(directory: Path, name: str) -> Path:
    """Where the files attached to the studies of study ``name`` live (the content of
    their optuna artifacts): ``<study folder>/<name>-artifacts``."""
    return directory / f"{name}-artifacts"


def attach_file(study: optuna.Study, path: Path, folder: Path) -> str:
    """Attach the file ``path`` to ``study`` as an optuna artifact kept in ``folder``;
    returns its artifact id.

    A file of the same name attached before is replaced (same id, new content), so
    a report made again is one artifact, not one per run.
    """
    from optuna.artifacts import FileSystemArtifactStore, get_all_artifact_meta, upload_artifact

    folder.mkdir(parents=True, exist_ok=True)
    store = FileSystemArtifactStore(folder)
    try:
        known = [m for m in get_all_artifact_meta(study) if m.filename == path.name]
    except (TypeError, KeyError):  # an artifact deleted in the dashboard leaves a null entry
        known = []
    if known:
        with path.open("rb") as content:
            store.write(known[0].artifact_id, content)
        return known[0].artifact_id
    return upload_artifact(artifact_store=store, file_path=str(path), study_or_trial=study)
