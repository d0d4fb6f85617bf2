"""What the study shows in optuna-dashboard: figures and a note.

Plotting libraries are imported here, where they are used.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import optuna

__all__ = ["attach_run_report"]


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
        import plotly.graph_objects as go
        from optuna_dashboard import save_note, save_plotly_graph_object
    except ImportError as error:  # optional: pip install .[plots,dashboard]
        warnings.warn(f"dashboard report skipped ({error.name} is not installed)", stacklevel=2)
        return False
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
    save_plotly_graph_object(study, figure, graph_object_id="verified-curves")
    save_note(study, note)
    return True
