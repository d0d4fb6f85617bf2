"""What the study's storage holds, read back for the report (nothing is written there).

Each part is read by the reader its command already has: the verify study by
:class:`~surrogate.identify._verify.Verifier` (the rule that chose the point), the
calibrations by :func:`~surrogate.calibration._diagnose.model_ladder` and
:func:`~surrogate.calibration._compare.latest_calibration`, the curves against the
measurements by :func:`~surrogate.calibration._compare.comparison` (the solver at
the calibrated point through the result cache; an external solver's curves from the
cache only, as one of its runs can take hours), the keyword text by
:func:`~surrogate.identify._export.export`. A part that is missing is ``None`` with
the sentence that says why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import optuna

from .._errors import InputDataError, SolverError
from ..calibration._compare import Comparison, comparison, latest_calibration
from ..calibration._diagnose import model_ladder
from ..calibration._problem import calibration_study_name, model_label
from ..identify._export import export
from ..identify._verify import Verification, Verifier, as_planned, verify_study_name
from ..storage._optuna import quiet_optuna
from ..storage._storage import open_storage, storage_errors, unstored
from ..study._measurements import MeasurementSet, load_measurements
from ..study._spec import StudySpec

__all__ = ["Calibration", "Findings", "Identification", "gather"]


@dataclass(frozen=True)
class Identification:
    """The verify study of ``surrogate run``.

    ``spec`` is the study as planned (the run's target); ``chosen`` the most preferred
    verified point that meets the target (None: none yet), ``best`` the best verified
    point; ``result`` the stored ``run --json`` record, if the run stored one;
    ``identifiability`` its statement (from the record or the dashboard note);
    ``differs`` the sentence saying how the study file differs from the plan, if it does.
    """

    study: str
    spec: StudySpec
    records: list[Verification]
    chosen: Verification | None
    best: Verification | None
    plan: dict[str, Any]
    result: dict[str, Any] | None
    identifiability: str | None
    differs: str | None


@dataclass(frozen=True)
class Calibration:
    """The calibrations of the study: the one shown (``model``, ``record``: its
    ``calibrate --json`` record, ``why``: why that model), the model ladder, and the
    stored diagnosis of that model (``diagnosis``: its ``diagnose --json`` record;
    ``verdict``: its verdict, also from the dashboard note of an older diagnosis) and its
    stored recommendation (``next_test``: the ``next-test --json`` record, with the hash of
    the data it was made on; ``data_sha256``: the data the calibration saw last)."""

    model: str
    study: str
    record: dict[str, Any]
    why: str
    ladder: list[dict[str, Any]]
    diagnosis: dict[str, Any] | None
    verdict: str | None
    next_test: dict[str, Any] | None = None
    data_sha256: str | None = None


@dataclass(frozen=True)
class Findings:
    """Everything the report shows; for each missing part, the sentence why
    (``missing``, by part: ``identification``, ``calibration``, ``comparison``,
    ``diagnosis``, ``export``, ``measurements``)."""

    spec: StudySpec
    storage: str
    identification: Identification | None
    calibration: Calibration | None
    comparison: Comparison | None
    measurements: MeasurementSet | None
    export_text: str | None
    missing: dict[str, str]


def gather(spec: StudySpec, url: str) -> Findings:
    """Read what ``url`` holds of study ``spec``; refuse a storage with nothing of it."""
    command = f"surrogate {'run' if spec.targets.f60_n else 'calibrate'} {spec.path}"
    if unstored(url, "the report") is not None:  # nothing is created where none is yet
        raise InputDataError(f"no storage at {url} yet; run `{command}` first")
    quiet_optuna()
    opened = open_storage(url)
    with storage_errors(url):
        summaries = optuna.get_all_study_summaries(opened, include_best_trial=False)
        names = {summary.study_name for summary in summaries}
        identification = _identification(spec, opened) if verify_study_name(spec) in names else None
        calibration = _calibration(spec, opened)
    if identification is None and calibration is None:
        raise InputDataError(f"nothing of study {spec.name!r} in {url} yet; run `{command}` first")
    missing = _missing(spec, identification, calibration)
    measurements = _measurements(spec, missing)
    return Findings(
        spec=spec,
        storage=url,
        identification=identification,
        calibration=calibration,
        comparison=_comparison(spec, url, calibration, missing),
        measurements=measurements,
        export_text=_export_text(spec, url, missing),
        missing=missing,
    )


def _missing(
    spec: StudySpec, identification: Identification | None, calibration: Calibration | None
) -> dict[str, str]:
    """The sentence each part without data says instead (the parts read later add theirs)."""
    path = spec.path
    missing = {}
    if identification is None:
        missing["identification"] = (
            f"No identification in this storage yet: run `surrogate run {path}`."
            if spec.targets.f60_n
            else "This study has no F60 target ([targets] f60_n): `surrogate run` does not apply."
        )
    if spec.measurements_file is None:
        none = (
            "This study has no measured curves ([measurements] file): nothing to calibrate, "
            "compare or diagnose."
        )
        return {
            **missing,
            **dict.fromkeys(("calibration", "comparison", "diagnosis", "next_test"), none),
        }
    if calibration is None:
        missing["calibration"] = (
            f"No calibration in this storage yet: run `surrogate calibrate {path}`."
        )
        missing["comparison"] = "No calibrated model to compare with the measured curves yet."
    if calibration is None or (calibration.diagnosis is None and calibration.verdict is None):
        missing["diagnosis"] = f"No diagnosis in this storage yet: run `surrogate diagnose {path}`."
    if calibration is None or calibration.next_test is None:
        missing["next_test"] = (
            f"No recommended test in this storage yet: run `surrogate next-test {path}` "
            "(the study's [design] says what the lab can vary)."
        )
    return missing


def _identification(spec: StudySpec, storage: Any) -> Identification:
    """The verify study read back with the rule of ``surrogate run``."""
    name = verify_study_name(spec)
    study = optuna.load_study(study_name=name, storage=storage)
    differs = None
    try:
        planned = as_planned(spec, study.user_attrs)
    except InputDataError as error:
        planned, differs = spec, str(error)
    verifier = Verifier(planned, study, progress=False)
    result = study.user_attrs.get("result")
    statement = (result or {}).get("identifiability", {}).get("statement")
    return Identification(
        study=name,
        spec=planned,
        records=sorted(verifier.records.values(), key=lambda r: r.number or 0),
        chosen=verifier.chosen(),
        best=verifier.best(),
        plan=dict(study.user_attrs),
        result=result,
        identifiability=statement or _note_part(study, "### Identifiability"),
        differs=differs,
    )


def _calibration(spec: StudySpec, storage: Any) -> Calibration | None:
    """The calibration of the study's model, else the one with the smallest RMSE."""
    ladder = model_ladder(storage, spec.name)
    if not ladder:
        return None
    own = model_label(spec.effects)
    steps = {step["model"]: step for step in ladder}
    if own in steps:
        step, why = steps[own], "the study's model ([model] effects)"
    else:
        step = min(ladder, key=lambda s: s["rmse_n"])
        why = (
            f"the study's own model ({own}) is not calibrated yet; shown: the calibrated "
            "model with the smallest RMSE"
        )
    name = calibration_study_name(spec, step["effects"])
    record = latest_calibration(storage, name)
    assert record is not None  # a step of the ladder has its record
    study = optuna.load_study(study_name=name, storage=storage)
    diagnosis = study.user_attrs.get("diagnosis")
    verdict = diagnosis["verdict"] if diagnosis else _note_part(study, "## Diagnosis:")
    attrs = study.user_attrs
    return Calibration(
        step["model"],
        name,
        record,
        why,
        ladder,
        diagnosis,
        verdict,
        attrs.get("next_test"),
        attrs.get("data_sha256"),
    )


def _note_part(study: optuna.Study, heading: str) -> str | None:
    """The text after ``heading`` in the study's dashboard note, up to the next heading
    (what an older run or diagnosis kept only there), or None."""
    try:
        from optuna_dashboard import get_note
    except ImportError:
        return None
    note = get_note(study)
    if heading not in note:
        return None
    text = note.split(heading, 1)[1].split("\n#", 1)[0].strip()
    return text.splitlines()[0].strip() if heading.startswith("## ") else text


def _measurements(spec: StudySpec, missing: dict[str, str]) -> MeasurementSet | None:
    if spec.measurements_file is None:
        return None
    try:
        return load_measurements(spec.measurements_file, file_format=spec.measurement_format)
    except InputDataError as error:
        missing["measurements"] = f"The measured curves cannot be read: {error}."
        return None


def _comparison(
    spec: StudySpec, url: str, calibration: Calibration | None, missing: dict[str, str]
) -> Comparison | None:
    """Measured against model at the shown calibration (the full solver, cached runs)."""
    if calibration is None:
        return None
    try:
        # an external solver's run can take hours: only what the result cache holds
        solve = spec.solver == "builtin"
        return comparison(spec, effects=calibration.record["effects"], storage=url, solve=solve)
    except (InputDataError, SolverError) as error:
        missing["comparison"] = f"The comparison could not be made: {error}."
        return None


def _export_text(spec: StudySpec, url: str, missing: dict[str, str]) -> str | None:
    try:
        with storage_errors(url):
            return export(spec, storage=url, units="mm-N-s").text
    except InputDataError as error:
        missing["export"] = f"No keyword snippet: {error}."
        return None
