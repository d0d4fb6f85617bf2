"""``report``: one self-contained HTML page of what a study's storage holds.

What an engineer signs off: the study, the full solver and its verification, the
identified (``surrogate run``) or calibrated (``surrogate calibrate``) coating with
what the data determine, the curves against the target or the measurements with
the residuals, the diagnosis and model ladder (``surrogate diagnose``) and the
LS-DYNA snippet (``surrogate export``). The page is written atomically and
attached to the study's studies as an optuna artifact, so ``surrogate dashboard``
lists it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .._errors import InputDataError
from .._io import atomic_write_text, check_output_file
from .._pool import one_blas_thread_within
from ..effects import check_effects
from ..storage._dashboard import artifact_folder, attach_file
from ..storage._storage import open_storage, redacted_url, storage_errors
from ..study._spec import StudySpec, load_study
from ._findings import Findings, gather
from ._html import render

__all__ = ["PARTS", "ReportResult", "report"]

PARTS = ("identification", "calibration", "comparison", "diagnosis", "next_test", "export")
"""The parts of the report that come from the storage (the study and solver always show)."""

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReportResult:
    """Keys of ``surrogate report --json``.

    ``output`` is the HTML file written; ``shown`` the parts (of :data:`PARTS`) with
    data; ``missing`` the sentence the page says instead, by part (``measurements``
    too, when the study names none or they cannot be read); ``attached`` the
    studies whose dashboard lists the page as an artifact.
    """

    output: str
    study: str
    storage: str
    shown: list[str]
    missing: dict[str, str]
    attached: list[str]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@one_blas_thread_within
def report(
    study: str | Path | StudySpec,
    *,
    output: str | Path | None = None,
    storage: str | None = None,
    plugins: Sequence[str] = (),
) -> ReportResult:
    """Write the report of ``study`` as one HTML file that opens with no network.

    Parameters
    ----------
    study : path or StudySpec
        The study file (after ``surrogate run``, ``calibrate`` or ``diagnose``).
    output : path, optional
        The HTML file (default: ``<study folder>/<study name>-report.html``).
    storage : str, optional
        Optuna storage URL (default: the study's).
    plugins : sequence of str
        Modules of effects the study's ``[model] effects`` name.

    Raises
    ------
    InputDataError
        Nothing of the study in the storage (or no storage), an output folder that
        does not exist or cannot be written, or plotly missing; nothing is written.
    """
    from .. import __version__

    spec = study if isinstance(study, StudySpec) else load_study(study)
    check_effects(spec.effects, plugins)
    target = Path(output) if output is not None else spec.directory / f"{spec.name}-report.html"
    check_output_file(target)
    _check_plotly()
    url = storage or spec.default_storage()
    findings = gather(spec, url)
    made = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    atomic_write_text(target, render(findings, generated=made, version=__version__))
    return ReportResult(
        output=str(target),
        study=spec.name,
        storage=redacted_url(url),
        shown=[part for part in PARTS if part not in findings.missing],
        missing=dict(findings.missing),
        attached=_attach(findings, target),
    )


def _check_plotly() -> None:
    try:
        import plotly  # noqa: F401
    except ImportError:
        raise InputDataError(
            "surrogate report draws its figures with plotly, which is not installed; "
            "pip install 'webbing-surrogate[plots]'"
        ) from None


def _attach(findings: Findings, page: Path) -> list[str]:
    """Attach ``page`` to the studies it reports on (optuna-dashboard lists it); a
    storage that refuses is a warning, not a failure: the page is written."""
    import optuna

    names = [
        part.study for part in (findings.identification, findings.calibration) if part is not None
    ]
    folder = artifact_folder(findings.spec.directory, findings.spec.name)
    attached = []
    try:
        with storage_errors(findings.storage):
            opened = open_storage(findings.storage)
            for name in names:
                attach_file(optuna.load_study(study_name=name, storage=opened), page, folder)
                attached.append(name)
    except (InputDataError, OSError) as error:
        _LOG.warning("the report is not attached in the dashboard: %s", error)
    return attached
