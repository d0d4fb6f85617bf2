"""``export``: the verified optimum of a study as LS-DYNA keyword text.

The optimum is read back from the study's Optuna storage (the ``<name>/verify``
trials written by ``surrogate run``), with the same rule that chose it there:
the most preferred verified point that meets the target and every constraint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._errors import InputDataError
from .._io import atomic_write_text
from ..effects import check_effects
from ..study._spec import StudySpec, load_study
from ..study._units import gpa_to_mpa

if TYPE_CHECKING:
    from ._verify import Verification

__all__ = ["EXPORT_FORMATS", "ExportResult", "export"]

EXPORT_FORMATS = ("lsdyna",)


@dataclass(frozen=True)
class ExportResult:
    """Keys of ``surrogate export --json``.

    ``parameters`` holds ``ECOAT``, ``SCOAT``, ``TCOAT`` in the deck's ``units``;
    ``text`` is the keyword snippet; ``output`` the file written (None: none).
    """

    format: str
    study: str
    storage: str
    trial_number: int
    ecoat_gpa: float
    scoat_gpa: float
    tcoat_mm: float
    f60_n: float
    theta_sat_deg: float
    units: str
    parameters: dict[str, float]
    text: str
    output: str | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def export(
    study: str | Path | StudySpec,
    *,
    format: str = "lsdyna",
    output: str | Path | None = None,
    storage: str | None = None,
    units: str = "mm-N-s",
    plugins: Sequence[str] = (),
) -> ExportResult:
    """The verified optimum of ``study`` as a ``*PARAMETER`` block and a commented
    ``*MAT_SEATBELT_2D`` coating snippet.

    Parameters
    ----------
    study : path or StudySpec
        The study file whose ``surrogate run`` verified a point.
    format : {"lsdyna"}
        Output format.
    output : path, optional
        Write the snippet there (atomically); otherwise only return it.
    storage : str, optional
        Optuna storage URL (default: the study's).
    units : {"mm-N-s", "mm-kg-ms", "m-kg-s"}
        Unit system of the target deck (MPa, GPa or Pa for the stresses).
    plugins : sequence of str
        Modules of effects the study's ``[model] effects`` name (checked, not used).

    Raises
    ------
    InputDataError
        Unknown format or units, no verify study in the storage, or no verified
        point that meets the target yet.
    """
    from ..solvers._lsdyna import LSDYNA_UNITS

    if format not in EXPORT_FORMATS:
        raise InputDataError(f"--format must be one of {', '.join(EXPORT_FORMATS)}, got {format!r}")
    if units not in LSDYNA_UNITS:
        raise InputDataError(f"--units must be one of {', '.join(LSDYNA_UNITS)}, got {units!r}")
    spec = study if isinstance(study, StudySpec) else load_study(study)
    check_effects(spec.effects, plugins)
    if output is not None and not Path(output).parent.exists():
        raise InputDataError(f"output folder {Path(output).parent} does not exist; create it first")
    url = storage or spec.default_storage()
    chosen, name = _verified_optimum(spec, url)
    values = _deck_values(chosen.params, units)
    text = _lsdyna_text(spec, chosen, values, units, name)
    if output is not None:
        atomic_write_text(output, text)
    return ExportResult(
        format=format,
        study=name,
        storage=url,
        trial_number=int(chosen.number or 0),  # a verified point is a trial
        ecoat_gpa=chosen.params["ecoat_gpa"],
        scoat_gpa=chosen.params["scoat_gpa"],
        tcoat_mm=chosen.params["tcoat_mm"],
        f60_n=float(chosen.f60_n),
        theta_sat_deg=float(chosen.theta_sat_deg),
        units=units,
        parameters=values,
        text=text,
        output=None if output is None else str(output),
    )


def _verified_optimum(spec: StudySpec, url: str) -> tuple[Verification, str]:
    import optuna

    from ..storage._optuna import quiet_optuna
    from ._verify import Verifier, verify_study_name

    quiet_optuna()
    name = verify_study_name(spec)
    if url.startswith("sqlite:///") and not Path(url.removeprefix("sqlite:///")).exists():
        raise InputDataError(f"storage {url} does not exist; run `surrogate run` first")
    try:
        study = optuna.load_study(study_name=name, storage=url)
    except KeyError:
        raise InputDataError(
            f"no study {name!r} in {url}; run `surrogate run` on the study file first"
        ) from None
    chosen = Verifier(spec, study, progress=False).chosen()
    if chosen is None:
        raise InputDataError(
            f"no verified point of {name!r} meets the target and every constraint yet; "
            "run `surrogate run` (with a larger --budget) first"
        )
    return chosen, name


def _deck_values(params: dict[str, float], units: str) -> dict[str, float]:
    from ..solvers._lsdyna import LSDYNA_UNITS

    stress, length, _ = LSDYNA_UNITS[units]
    return {
        "ECOAT": gpa_to_mpa(params["ecoat_gpa"]) / stress,
        "SCOAT": gpa_to_mpa(params["scoat_gpa"]) / stress,
        "TCOAT": params["tcoat_mm"] / length,
    }


def _lsdyna_text(
    spec: StudySpec, chosen: Verification, values: dict[str, float], units: str, name: str
) -> str:
    from ..solvers._lsdyna import FIELD, fill_parameters

    stress = {"mm-N-s": "MPa", "mm-kg-ms": "GPa", "m-kg-s": "Pa"}[units]
    length = "m" if units == "m-kg-s" else "mm"
    target = spec.targets.f60_n
    header = [
        "$ Coating of *MAT_SEATBELT_2D identified by surrogate",
        f"$ study {name}, verify trial #{chosen.number}, solver {spec.solver}",
        f"$ verified: F60 = {chosen.f60_n:.4g} N"
        + (f" (target {target:.4g} N +/- {100 * spec.targets.tolerance:g} %)" if target else "")
        + f", theta_sat = {chosen.theta_sat_deg:g} deg",
        f"$ units {units}: ECOAT, SCOAT in {stress}, TCOAT in {length}",
        "*KEYWORD",
    ]
    block = fill_parameters("\n".join(header), values).splitlines()
    from ..solvers._lsdyna import format_real

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
            [" " * 2 * FIELD] + [format_real(values[name]) for name in ("ECOAT", "TCOAT", "SCOAT")]
        )[1:],
    ]
    return "\n".join([line for line in block if line != "*KEYWORD"] + snippet) + "\n"
