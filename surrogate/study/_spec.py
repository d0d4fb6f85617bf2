"""Study files (``studies/*.toml``): one schema for every command.

Validated on load into a frozen :class:`StudySpec`; a bad file raises
:class:`InputDataError` with one line naming the key, the value and the fix,
before anything is written anywhere.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._errors import InputDataError
from ._cluster import ClusterSettings, cluster_settings
from ._design import DesignSpec, design_settings
from ._formats import MeasurementFormat
from ._keys import keys
from ._rig import Rig
from ._space import COATING_PARAMETERS, PAPER_SPACE, ParameterSpace, ParameterSpec

__all__ = ["Budget", "Constraints", "StudySpec", "Targets", "load_study"]

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
_UNITS = {"ecoat_gpa": "GPa", "scoat_gpa": "GPa", "tcoat_mm": "mm"}
_SECTIONS = keys("")  # every key of a study file: ._keys


@dataclass(frozen=True)
class Targets:
    """Scalar targets: F60 [N] with a relative tolerance."""

    f60_n: float | None = None
    tolerance: float = 0.01


@dataclass(frozen=True)
class Constraints:
    """``c(x) ≤ 0`` is feasible; each field is one rule (None: not imposed)."""

    theta_sat_deg_min: float | None = 80.0
    tcoat_max_fraction_of_thickness: float | None = 0.1


@dataclass(frozen=True)
class Budget:
    """Full-solver runs: the initial design, the cap on the search, candidates per
    iteration, cheap surrogate trials per iteration, and the runs spent after
    verification on the exact sensitivities (on top of the cap; 0: use the
    surrogate's)."""

    initial_samples: int = 5
    max_solver_calls: int = 30
    candidates_per_iteration: int = 1
    surrogate_trials: int = 300
    identifiability_runs: int = 3
    calibration_solver_calls: int = 200

    def check_main_job(self, low_fidelity: bool, name: str) -> None:
        """Room for the main job's start within ``max_solver_calls`` (``name`` says where
        it was set): its initial design of ``initial_samples`` runs on the full solver;
        with the built-in solver as the prior of an external one the corrected model's
        first answer, one run, so any budget ≥ 1 (the design runs only if the correction
        is dropped, with the runs left)."""
        if not low_fidelity and self.max_solver_calls < self.initial_samples:
            raise InputDataError(
                f"{name} ({self.max_solver_calls}) must be ≥ "
                f"budget.initial_samples ({self.initial_samples})"
            )


@dataclass(frozen=True)
class StudySpec:
    """A validated study file."""

    name: str
    path: Path | None
    seed: int = 0
    solver: str = "builtin"
    solver_settings: dict[str, Any] = field(default_factory=dict)
    multi_fidelity: bool = True
    rig: Rig = field(default_factory=Rig)
    space: ParameterSpace = PAPER_SPACE
    targets: Targets = field(default_factory=Targets)
    measurements_file: Path | None = None
    noise_n: float | None = None
    measurement_format: MeasurementFormat = field(default_factory=MeasurementFormat)
    constraints: Constraints = field(default_factory=Constraints)
    preference_order: tuple[str, ...] = ("tcoat_mm", "scoat_gpa")
    effects: tuple[str, ...] = ()
    budget: Budget = field(default_factory=Budget)
    storage: str | None = None
    cluster: ClusterSettings = field(default_factory=ClusterSettings)  # [cluster], validated
    design: DesignSpec = field(default_factory=DesignSpec)  # [design], validated

    @property
    def low_fidelity(self) -> bool:
        """Whether the built-in solver is the fast prior of this study's (external)
        full solver (``[solver] multi_fidelity``, on by default for external kinds)."""
        from ..solvers._fidelity import uses_low_fidelity

        return uses_low_fidelity(self.solver, self.multi_fidelity)

    @property
    def directory(self) -> Path:
        return self.path.parent if self.path is not None else Path.cwd()

    def default_storage(self) -> str:
        """``sqlite:///`` file next to the study file."""
        if self.storage:
            return self.storage
        return f"sqlite:///{(self.directory / f'{self.name}.db').resolve()}"


def load_study(path: str | Path) -> StudySpec:
    """Read and validate a study file."""
    path = Path(path)
    if not path.exists():
        raise InputDataError(f"study file {path} does not exist; check the path")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as error:
        raise InputDataError(f"{path}: not valid TOML ({error})") from None
    except UnicodeDecodeError:
        raise InputDataError(f"{path}: not a UTF-8 text file") from None
    return parse_study(data, path)


def parse_study(data: dict[str, Any], path: Path | None = None) -> StudySpec:
    """Validate the parsed TOML of a study file (``path`` resolves relative paths)."""
    where = str(path) if path is not None else "study"
    _only(data, _SECTIONS, where, "")
    name, seed, storage = _study(_section(data, "study", where), where)
    kind, solver_settings, multi_fidelity = _solver(_section(data, "solver", where), where, path)
    rig = _rig(_section(data, "rig", where), where)
    space = _space(_section(data, "parameters", where), where)
    targets = _targets(data, where)
    measurements, noise, file_format = _measurements(data, where, path)
    constraints = _constraints(_section(data, "constraints", where), where)
    order = _preferences(_section(data, "preferences", where), space, where)
    effects = _effects(_section(data, "model", where), where)
    budget = _budget(_section(data, "budget", where), where)
    if targets.f60_n is None and measurements is None:
        raise InputDataError(
            f"{where}: a study needs [targets] f60_n or [measurements] file; add one"
        )
    spec = StudySpec(
        name=name,
        path=path,
        seed=seed,
        solver=kind,
        solver_settings=solver_settings,
        multi_fidelity=multi_fidelity,
        rig=rig,
        space=space,
        targets=targets,
        measurements_file=measurements,
        noise_n=noise,
        measurement_format=file_format,
        constraints=constraints,
        preference_order=order,
        effects=effects,
        budget=budget,
        storage=storage,
        cluster=cluster_settings(_section(data, "cluster", where), where),
        design=design_settings(_section(data, "design", where), where),
    )
    spec.budget.check_main_job(spec.low_fidelity, f"{where}: budget.max_solver_calls")
    return spec


def _study(section: dict[str, Any], where: str) -> tuple[str, int, str | None]:
    """``[study]``: the name, the seed and the storage URL (None: next to the file)."""
    _only(section, keys("study"), where, "study")
    name = section.get("name")
    if name is None:
        raise InputDataError(
            f'{where}: no [study] name; a study file starts with [study] and name = "my-study"'
        )
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputDataError(
            f"{where}: [study] name must be 1–64 letters, digits, '_', '.' or '-', got {name!r}"
        )
    seed = _int(section.get("seed", 0), where, "study.seed", low=0)
    storage = section.get("storage")
    if storage is not None and not isinstance(storage, str):
        raise InputDataError(f"{where}: [study] storage must be a URL string, got {storage!r}")
    return name, seed, storage


def _preferences(section: dict[str, Any], space: ParameterSpace, where: str) -> tuple[str, ...]:
    """``[preferences] order``: the parameters to keep low among equals, first first."""
    _only(section, keys("preferences"), where, "preferences")
    order = tuple(section.get("order", ("tcoat_mm", "scoat_gpa")))
    for item in order:
        if item not in space.names:
            raise InputDataError(
                f"{where}: [preferences] order names {item!r}, which is not a "
                f"parameter; use some of {', '.join(space.names)}"
            )
    return order


def _effects(section: dict[str, Any], where: str) -> tuple[str, ...]:
    """``[model] effects``: the names of the effects to switch on, each once."""
    _only(section, keys("model"), where, "model")
    effects = section.get("effects", [])
    if not isinstance(effects, list) or not all(
        isinstance(e, str) and e.isidentifier() for e in effects
    ):
        raise InputDataError(
            f"{where}: [model] effects must be a list of effect names such as "
            f'["tension"], got {effects!r}'
        )
    if len(set(effects)) != len(effects):
        raise InputDataError(f"{where}: [model] effects names an effect twice: {effects!r}")
    return tuple(effects)


def _solver(
    section: dict[str, Any], where: str, path: Path | None
) -> tuple[str, dict[str, Any], bool]:
    """``[solver]``: the kind (one of the solver registry's), its validated settings
    (see :mod:`surrogate.solvers`) and ``multi_fidelity`` (the built-in solver as the
    fast prior of an external one; on by default)."""
    from ..solvers import available_solvers, get_solver

    settings = dict(section)
    kind = settings.pop("kind", "builtin")
    kinds = available_solvers()
    if kind not in kinds:
        raise InputDataError(
            f"{where}: [solver] kind must be one of {', '.join(kinds)}, got {kind!r}"
        )
    multi_fidelity = settings.pop("multi_fidelity", True)
    if not isinstance(multi_fidelity, bool):
        raise InputDataError(
            f"{where}: [solver] multi_fidelity must be true or false, got {multi_fidelity!r}"
        )
    base = path.parent if path is not None else Path.cwd()
    for key in ("template", "workdir_root"):
        if isinstance(settings.get(key), str):
            settings[key] = str((base / settings[key]).resolve())
    try:
        return kind, get_solver(kind).check_settings(settings), multi_fidelity
    except InputDataError as error:
        raise InputDataError(f"{where}: {error}") from None


def _section(data: dict[str, Any], name: str, where: str) -> dict[str, Any]:
    section = data.get(name, {})
    if not isinstance(section, dict):
        raise InputDataError(f"{where}: [{name}] must be a table, got {section!r}")
    return section


def _only(section: dict[str, Any], allowed: tuple[str, ...], where: str, name: str) -> None:
    for key in section:
        if key not in allowed:
            place = f"in [{name}]" if name else "section"
            raise InputDataError(f"{where}: unknown {place} {key!r}; allowed: {', '.join(allowed)}")


def _int(value: Any, where: str, key: str, *, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputDataError(f"{where}: {key} must be a whole number ≥ {low}, got {value!r}")
    return value


def _positive(value: Any, where: str, key: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not value > 0
        or value != value
        or value == float("inf")
    ):
        raise InputDataError(f"{where}: {key} must be a number > 0, got {value!r}")
    return float(value)


def _rig(section: dict[str, Any], where: str) -> Rig:
    _only(section, keys("rig"), where, "rig")
    try:
        return Rig(**section)
    except InputDataError as error:
        raise InputDataError(f"{where}: [rig] {error}") from None


def _space(section: dict[str, Any], where: str) -> ParameterSpace:
    if not section:
        return PAPER_SPACE
    specs = []
    for name, value in section.items():
        if name not in COATING_PARAMETERS:
            raise InputDataError(
                f"{where}: [parameters] {name!r} is not a coating parameter; "
                f"use {', '.join(COATING_PARAMETERS)}"
            )
        if not isinstance(value, dict):
            raise InputDataError(
                f"{where}: [parameters] {name} must be "
                f"{{ low = …, high = …, log = true }}, got {value!r}"
            )
        _only(value, keys("parameters.*"), where, f"parameters.{name}")
        unit = value.get("unit", _UNITS[name])
        if unit != _UNITS[name]:
            raise InputDataError(
                f"{where}: [parameters] {name} is in {_UNITS[name]}, got unit "
                f"{unit!r}; convert the bounds"
            )
        try:
            specs.append(
                ParameterSpec(
                    name,
                    _positive(value.get("low"), where, f"{name}.low"),
                    _positive(value.get("high"), where, f"{name}.high"),
                    log=bool(value.get("log", True)),
                    unit=unit,
                )
            )
        except InputDataError as error:
            raise InputDataError(f"{where}: [parameters] {error}") from None
    missing = [n for n in COATING_PARAMETERS if n not in section]
    if missing:
        raise InputDataError(
            f"{where}: [parameters] must declare all of "
            f"{', '.join(COATING_PARAMETERS)}; missing {', '.join(missing)}"
        )
    return ParameterSpace(tuple(specs))


def _targets(data: dict[str, Any], where: str) -> Targets:
    section = _section(data, "targets", where)
    _only(section, keys("targets"), where, "targets")
    f60 = section.get("f60_n")
    f60 = None if f60 is None else _positive(f60, where, "targets.f60_n")
    tolerance = _positive(section.get("tolerance", 0.01), where, "targets.tolerance")
    if tolerance >= 1.0:
        raise InputDataError(
            f"{where}: targets.tolerance is relative and must be < 1, got {tolerance:g}"
        )
    return Targets(f60, tolerance)


_FORMAT_KEYS = tuple(f for f in MeasurementFormat.__dataclass_fields__ if f != "conditions")


def _measurements(
    data: dict[str, Any], where: str, path: Path | None
) -> tuple[Path | None, float | None, MeasurementFormat]:
    """``[measurements]``: the file (or glob), ``noise_n`` and how the files are read
    (:class:`MeasurementFormat`; relative paths are relative to the study file)."""
    section = _section(data, "measurements", where)
    _only(section, keys("measurements"), where, "measurements")
    file = section.get("file", _section(data, "targets", where).get("measurements"))
    noise = section.get("noise_n")
    noise = None if noise is None else _positive(noise, where, "measurements.noise_n")
    resolved = None if file is None else _project_path(file, where, "measurements file", path)
    given = [key for key in section if key not in ("file", "noise_n")]
    if given and resolved is None:
        raise InputDataError(
            f'{where}: [measurements] {given[0]} is set but no file; add file = "tests/*.csv"'
        )
    conditions = section.get("conditions")
    try:
        file_format = MeasurementFormat(
            **{key: section[key] for key in _FORMAT_KEYS if key in section},
            conditions=None
            if conditions is None
            else _project_path(conditions, where, "measurements conditions", path),
        )
    except InputDataError as error:
        raise InputDataError(f"{where}: [measurements] {error}") from None
    return resolved, noise, file_format


def _project_path(value: Any, where: str, key: str, path: Path | None) -> Path:
    """A path string of the study file, resolved; refused if it leaves the project folder
    (the study file's folder's parent)."""
    if not isinstance(value, str):
        raise InputDataError(f"{where}: {key} must be a path string, got {value!r}")
    base = path.parent if path is not None else Path.cwd()
    resolved = (base / value).resolve()
    if not resolved.is_relative_to(base.resolve().parent):
        raise InputDataError(
            f"{where}: {key} {value!r} leaves the project folder; keep data under it"
        )
    return resolved


def _constraints(section: dict[str, Any], where: str) -> Constraints:
    _only(section, keys("constraints"), where, "constraints")
    theta = section.get("theta_sat_deg_min", 80.0)
    fraction = section.get("tcoat_max_fraction_of_thickness", 0.1)
    if theta is not None:
        theta = _positive(theta, where, "constraints.theta_sat_deg_min")
        if theta > 90.0:
            raise InputDataError(
                f"{where}: constraints.theta_sat_deg_min must be ≤ 90 "
                f"(the tested range), got {theta:g}"
            )
    if fraction is not None:
        fraction = _positive(fraction, where, "constraints.tcoat_max_fraction_of_thickness")
        if fraction >= 0.5:
            raise InputDataError(
                f"{where}: constraints.tcoat_max_fraction_of_thickness must be "
                f"< 0.5, got {fraction:g}"
            )
    return Constraints(theta, fraction)


def _budget(section: dict[str, Any], where: str) -> Budget:
    _only(section, keys("budget"), where, "budget")
    default = Budget()
    initial = _int(
        section.get("initial_samples", default.initial_samples),
        where,
        "budget.initial_samples",
        low=3,
    )
    calls = _int(
        section.get("max_solver_calls", default.max_solver_calls),
        where,
        "budget.max_solver_calls",
        low=1,
    )
    per = _int(
        section.get("candidates_per_iteration", default.candidates_per_iteration),
        where,
        "budget.candidates_per_iteration",
        low=1,
    )
    trials = _int(
        section.get("surrogate_trials", default.surrogate_trials),
        where,
        "budget.surrogate_trials",
        low=10,
    )
    identifiability = _int(
        section.get("identifiability_runs", default.identifiability_runs),
        where,
        "budget.identifiability_runs",
        low=0,
    )
    calibration = _int(
        section.get("calibration_solver_calls", default.calibration_solver_calls),
        where,
        "budget.calibration_solver_calls",
        low=1,  # what a calibration needs is its loop's (a refusal before any run)
    )
    return Budget(initial, calls, per, trials, identifiability, calibration)
