"""``export``: a verified coating as LS-DYNA keyword text (``*MAT_SEATBELT_2D``, card 3).

Two sources, each read back from the study's Optuna storage with the rule that
chose it there:

- ``run`` (a study with an F60 target): the most preferred verified point of
  ``<name>/verify`` that meets the target and every constraint;
- ``calibration`` (a study with measured curves): the calibrated point of the
  study's model (``<name>/calibrate/<model>``). The card has no tension, rate or
  direction dependence, so the coat is evaluated at the conditions the user names
  (``at``), through the one model-state path every solver takes; what the card
  cannot carry (hardening, a clamp's compliance, self-weight …) is named.

TCOAT's sign is read two ways in circulation (:data:`TCOAT_CONVENTIONS`); the
snippet states the one written and what the others would read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .._errors import InputDataError
from .._io import atomic_write_text, check_output_file
from ..effects import ModelState, check_effects, get_effect
from ..solvers._state import coating_state, model_state_of
from ..study._spec import StudySpec, load_study
from ..study._units import mpa_to_gpa

__all__ = ["EXPORT_FORMATS", "EXPORT_SOURCES", "TCOAT_CONVENTIONS", "ExportResult", "export"]

EXPORT_FORMATS = ("lsdyna",)
EXPORT_SOURCES = ("run", "calibration")
TCOAT_CONVENTIONS = {
    "thickness": "TCOAT > 0 is the coat's thickness in every LS-DYNA version; LS-DYNA "
    "then adds the coat to the membrane's tension stiffness too (this model: bending only)",
    "bending-only": "TCOAT < 0 read as in LS-DYNA R12 and *MAT_FABRIC FORM = -14: a coat "
    "|TCOAT| thick that stiffens bending only, as in this model; recent manuals read a "
    "negative TCOAT as a ratio to the shell thickness instead",
    "ratio": "TCOAT < 0 read as in recent *MAT_SEATBELT_2D manuals: |TCOAT| is the coat's "
    "thickness over the shell's (the webbing thickness of the study's rig); LS-DYNA R12 "
    "reads it as a thickness instead",
}
"""How TCOAT is written; the default ``thickness`` is the one reading every version shares."""
_COAT_FIELDS = ("ecoat_mpa", "scoat_mpa", "tcoat_mm")


@dataclass(frozen=True)
class ExportResult:
    """Keys of ``surrogate export --json``.

    ``source`` is ``run`` or ``calibration``; ``status`` the source's
    (``verified``; ``converged``, ``budget_exhausted`` or ``stalled``). ``ecoat_gpa``,
    ``scoat_gpa``, ``tcoat_mm`` are the coat the card carries (for a calibration:
    evaluated at ``conditions``); ``parameters`` holds ``ECOAT``, ``SCOAT``,
    ``TCOAT`` as written (deck ``units``, TCOAT by ``tcoat_convention``);
    ``not_carried`` the enabled effects the card cannot carry. ``trial_number``,
    ``f60_n``, ``theta_sat_deg`` are the run's (None for a calibration),
    ``rmse_n`` the calibration's (None for a run); ``output`` the file written.

    ``format`` is the output format (``lsdyna``); ``study`` and ``storage`` the Optuna
    study read and its storage; ``units`` the deck's units; ``tcoat_convention`` how
    TCOAT was written (``thickness``, ``bending-only`` or ``ratio``); ``text`` the
    keyword text.
    """

    format: str
    source: str
    status: str
    study: str
    storage: str
    trial_number: int | None
    ecoat_gpa: float
    scoat_gpa: float
    tcoat_mm: float
    f60_n: float | None
    theta_sat_deg: float | None
    rmse_n: float | None
    conditions: dict[str, Any]
    not_carried: list[str]
    tcoat_convention: str
    units: str
    parameters: dict[str, float]
    text: str
    output: str | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class _Source:
    """What is exported: where it came from and the lines that say so."""

    kind: str
    status: str
    study: str
    state: ModelState
    says: list[str]
    trial_number: int | None = None
    f60_n: float | None = None
    theta_sat_deg: float | None = None
    rmse_n: float | None = None
    not_carried: list[str] = field(default_factory=list)


def export(
    study: str | Path | StudySpec,
    *,
    format: str = "lsdyna",
    output: str | Path | None = None,
    storage: str | None = None,
    units: str = "mm-N-s",
    tcoat: str = "thickness",
    source: str | None = None,
    at: Mapping[str, Any] | None = None,
    effects: Sequence[str] | None = None,
    plugins: Sequence[str] = (),
) -> ExportResult:
    """A verified coating of ``study`` as a ``*PARAMETER`` block and a commented
    ``*MAT_SEATBELT_2D`` card 3.

    Parameters
    ----------
    study : path or StudySpec
        The study file (after ``surrogate run`` or ``surrogate calibrate``).
    format : {"lsdyna"}
        Output format.
    output : path, optional
        Write the snippet there (atomically); otherwise only return it.
    storage : str, optional
        Optuna storage URL (default: the study's).
    units : {"mm-N-s", "mm-kg-ms", "m-kg-s"}
        Unit system of the target deck (MPa, GPa or Pa for the stresses).
    tcoat : {"thickness", "bending-only", "ratio"}
        How TCOAT is written (:data:`TCOAT_CONVENTIONS`).
    source : {"run", "calibration"}, optional
        Default: ``run`` for a study with an F60 target, else ``calibration``
        (of the study's ``[model] effects``).
    at : mapping, optional
        Conditions at which a calibrated coat is evaluated (each one an enabled
        effect reads must be given), e.g. ``{"tension_n": 40}``.
    effects : sequence of str, optional
        The calibrated model's effects (default: the study's ``[model] effects``).
    plugins : sequence of str
        Modules of the effects named.
    """
    from ..solvers._lsdyna import LSDYNA_UNITS

    _check_choice("--format", format, EXPORT_FORMATS)
    _check_choice("--units", units, tuple(LSDYNA_UNITS))
    _check_choice("--tcoat", tcoat, tuple(TCOAT_CONVENTIONS))
    spec = study if isinstance(study, StudySpec) else load_study(study)
    check_effects(spec.effects, plugins)
    model = tuple(spec.effects) if effects is None else tuple(check_effects(effects, plugins))
    kind = source or ("run" if spec.targets.f60_n is not None else "calibration")
    _check_choice("--from", kind, EXPORT_SOURCES)
    if kind == "run" and model:
        raise InputDataError(
            "a surrogate run point has no effects; export a calibration (--from calibration)"
        )
    if output is not None:
        check_output_file(output)
    url = storage or spec.default_storage()
    conditions = dict(at or {})
    found = (
        _verified_run(spec, url, conditions)
        if kind == "run"
        else _calibrated(spec, model, url, conditions)
    )
    values = card_values(found.state, units, tcoat)
    text = _lsdyna_text(found, values, units, tcoat)
    if output is not None:
        atomic_write_text(output, text)
    return ExportResult(
        format=format,
        source=found.kind,
        status=found.status,
        study=found.study,
        storage=url,
        trial_number=found.trial_number,
        ecoat_gpa=mpa_to_gpa(found.state.ecoat_mpa),
        scoat_gpa=mpa_to_gpa(found.state.scoat_mpa),
        tcoat_mm=found.state.tcoat_mm,
        f60_n=found.f60_n,
        theta_sat_deg=found.theta_sat_deg,
        rmse_n=found.rmse_n,
        conditions=conditions,
        not_carried=found.not_carried,
        tcoat_convention=tcoat,
        units=units,
        parameters=values,
        text=text,
        output=None if output is None else str(output),
    )


def _check_choice(option: str, value: str, choices: Sequence[str]) -> None:
    if value not in choices:
        raise InputDataError(f"{option} must be one of {', '.join(choices)}, got {value!r}")


def card_values(state: ModelState, units: str, tcoat: str) -> dict[str, float]:
    """``ECOAT``, ``SCOAT``, ``TCOAT`` of card 3 in the deck's ``units``, TCOAT by
    its convention (a ratio is over the webbing thickness of the state's rig)."""
    from ..solvers._lsdyna import coating_parameters

    values = coating_parameters(state, units=units)
    values.pop("HCOAT", None)  # no field on card 3: named among what it cannot carry
    if tcoat == "bending-only":
        values["TCOAT"] = -values["TCOAT"]
    elif tcoat == "ratio":
        values["TCOAT"] = -state.tcoat_mm / state.rig.thickness_mm
    return values


# -- the sources ------------------------------------------------------------------------------
def _verified_run(spec: StudySpec, url: str, conditions: Mapping[str, Any]) -> _Source:
    """The point ``surrogate run`` chose (its study has no effects: the coat is the point)."""
    from ._verify import Verifier

    if conditions:
        raise InputDataError(
            "--at is for a calibrated coat whose effects read conditions; "
            "a surrogate run point has none"
        )
    study, name = _load(spec, url, "verify", "surrogate run")
    chosen = Verifier(spec, study, progress=False).chosen()
    if chosen is None:
        stalled = (study.user_attrs.get("result") or {}).get("status") == "stalled"
        raise InputDataError(
            f"no verified point of {name!r} meets the target and every constraint yet; "
            + (
                "its last `surrogate run` stalled with runs left (its message says why: a "
                "larger --budget would not have been spent)"
                if stalled
                else "run `surrogate run` (with a larger --budget) first"
            )
        )
    p = chosen.params
    target = spec.targets.f60_n
    return _Source(
        kind="run",
        status="verified",
        study=name,
        state=coating_state(p["ecoat_gpa"], p["scoat_gpa"], p["tcoat_mm"], spec.rig),
        says=[
            f"study {name}, verify trial #{chosen.number}, solver {spec.solver}",
            f"verified: F60 = {chosen.f60_n:.4g} N"
            + (f" (target {target:.4g} N +/- {100 * spec.targets.tolerance:g} %)" if target else "")
            + f", theta_sat = {chosen.theta_sat_deg:g} deg",
        ],
        trial_number=chosen.number,
        f60_n=float(chosen.f60_n),
        theta_sat_deg=float(chosen.theta_sat_deg),
    )


def _calibrated(
    spec: StudySpec, model: Sequence[str], url: str, conditions: Mapping[str, Any]
) -> _Source:
    """The calibrated coat of the model with the effects ``model``, at ``conditions``."""
    from ..calibration._problem import model_label

    label = model_label(model)
    study, name = _load(spec, url, f"calibrate/{label}", "surrogate calibrate")
    result = study.user_attrs.get("result")
    if not isinstance(result, dict) or "params" not in result:
        raise InputDataError(
            f"{name!r} in {url} holds no calibration result (`compare --params` stores only "
            "its figures there); run `surrogate calibrate` for this model first"
        )
    params = result["params"]
    effects: dict[str, dict[str, float]] = {effect: {} for effect in model}
    for key, value in params.items():
        if "." in key:
            effect, parameter = key.split(".", 1)
            effects.setdefault(effect, {})[parameter] = value
    _check_read_conditions(effects, conditions)
    coat = (params["ecoat_gpa"], params["scoat_gpa"], params["tcoat_mm"])
    state = model_state_of(*coat, spec.rig, effects, conditions)
    at = ", ".join(f"{k}={v}" for k, v in conditions.items()) or "no conditions"
    return _Source(
        kind="calibration",
        status=str(result.get("status")),
        study=name,
        state=state,
        says=[
            f"study {name}, solver {spec.solver}, calibration {result.get('status')}: "
            f"RMSE {result['rmse_n']:.4g} N (noise {result['noise_n']:.4g} N), "
            f"misfit {result.get('misfit') or 'not stated'}",
            f"calibrated coat Ecoat {coat[0]:.6g} GPa, Scoat {coat[1]:.6g} GPa, "
            f"Tcoat {coat[2]:.6g} mm; the card's coat evaluated at {at}",
        ],
        rmse_n=float(result["rmse_n"]),
        not_carried=_not_carried(coat, spec, effects, conditions),
    )


def _check_read_conditions(
    effects: Mapping[str, Mapping[str, float]], conditions: Mapping[str, Any]
) -> None:
    for name in effects:
        for condition in get_effect(name).reads:
            if condition not in conditions:
                raise InputDataError(
                    f"effect {name!r} reads the test condition {condition}; name the "
                    f"conditions the card stands for: --at {condition}=VALUE"
                )


def _not_carried(
    coat: tuple[float, float, float],
    spec: StudySpec,
    effects: Mapping[str, Mapping[str, float]],
    conditions: Mapping[str, Any],
) -> list[str]:
    """Each enabled effect that changes more than the coat (``hardening (hardening_ratio)``)."""
    base = model_state_of(*coat, spec.rig, None, conditions)
    named = []
    for name, values in effects.items():
        alone = model_state_of(*coat, spec.rig, {name: values}, conditions)
        changed = [
            key
            for key, value in asdict(alone).items()
            if key not in _COAT_FIELDS and not _same_value(value, asdict(base)[key])
        ]
        if changed:
            named.append(f"{name} ({', '.join(changed)})")
    return named


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return bool(a == b)


def _load(spec: StudySpec, url: str, suffix: str, command: str) -> tuple[Any, str]:
    import optuna

    from ..storage._optuna import quiet_optuna
    from ..storage._storage import open_storage, unstored

    quiet_optuna()
    name = f"{spec.name}/{suffix}"
    if unstored(url, "export") is not None:  # a journal would be created, not read
        raise InputDataError(f"storage {url} does not exist; run `{command}` first")
    try:
        return optuna.load_study(study_name=name, storage=open_storage(url)), name
    except KeyError:
        raise InputDataError(
            f"no study {name!r} in {url}; run `{command}` on the study file first"
        ) from None


# -- the text ---------------------------------------------------------------------------------
def _lsdyna_text(found: _Source, values: dict[str, float], units: str, tcoat: str) -> str:
    from ..solvers._lsdyna import FIELD, fill_parameters, format_real

    stress = {"mm-N-s": "MPa", "mm-kg-ms": "GPa", "m-kg-s": "Pa"}[units]
    length = "m" if units == "m-kg-s" else "mm"
    tcoat_unit = "(a ratio)" if tcoat == "ratio" else f"in {length}"
    header = [
        "$ Coating of *MAT_SEATBELT_2D identified by surrogate",
        *(line for text in found.says for line in _wrapped(text)),
        f"$ units {units}: ECOAT, SCOAT in {stress}, TCOAT {tcoat_unit}",
        *_wrapped(f"TCOAT convention '{tcoat}': {TCOAT_CONVENTIONS[tcoat]}."),
        "$ ECOAT is the coat's modulus itself (positive), in every convention.",
        *_not_carried_lines(found.not_carried),
        "*KEYWORD",
    ]
    block = fill_parameters("\n".join(header), values).splitlines()
    snippet = [
        "$",
        "$ *MAT_SEATBELT_2D, card 3: the coating fields. Refer to the parameters above or",
        "$ use the values; to use a line, replace its '$' in column 1 by a blank and keep",
        "$ your deck's P1DOFF and FORM (fields 1-2). TCOAT comes before SCOAT on this card",
        "$ (unlike *MAT_FABRIC).",
        "$#  p1doff      form     ecoat     tcoat     scoat",
        "$" + "".join(v.rjust(FIELD) for v in ("", "", "&ECOAT", "&TCOAT", "&SCOAT"))[1:],
        "$"
        + "".join(
            # one blank at least between fields, so the line also reads as free format
            [" " * 2 * FIELD]
            + [
                format_real(values[name], FIELD - 1).rjust(FIELD)
                for name in ("ECOAT", "TCOAT", "SCOAT")
            ]
        )[1:],
    ]
    return "\n".join([line for line in block if line != "*KEYWORD"] + snippet) + "\n"


def _not_carried_lines(effects: list[str]) -> list[str]:
    if not effects:
        return []
    return _wrapped(
        f"the card cannot carry: {'; '.join(effects)}. Model them elsewhere in your deck "
        "or accept the difference."
    )


def _wrapped(text: str) -> list[str]:
    import textwrap

    return [f"$ {line}" for line in textwrap.wrap(text, width=78, break_on_hyphens=False)]
