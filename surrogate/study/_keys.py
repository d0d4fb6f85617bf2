"""The keys of a study file, declared once: section, name, type, default, meaning.

The study-file loader (:mod:`surrogate.study._spec`) refuses any key not declared
here (:func:`keys`), and the manual's reference of the study file is generated from
this table at build time, so the two cannot drift apart. Add a key here *and* read it
in the loader; a test checks the defaults below against the loader's records.

Two sections are declared elsewhere and only read here: ``[rig]`` is the fields of
:class:`~surrogate.study._rig.Rig` (their meanings from its docstring), and the
``[solver]`` settings beyond ``kind`` and ``multi_fidelity`` are each solver's
``settings_keys`` (their meanings in :data:`SOLVER_SETTINGS`).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any

from ._rig import Rig
from ._space import COATING_PARAMETERS

__all__ = ["KEYS", "REQUIRED", "SECTIONS", "SOLVER_SETTINGS", "StudyKey", "keys", "rig_keys"]

REQUIRED = "required"
"""The default of a key that has none: the file must give it."""


@dataclass(frozen=True)
class StudyKey:
    """One key of a study file.

    ``section`` is the TOML table (``"budget"``; ``"parameters.*"`` for the table of
    each coating parameter), ``type`` the TOML type as a reader writes it, ``default``
    the value used when the key is absent (:data:`REQUIRED`: none; ``None``: not
    imposed / not set), ``meaning`` one or two sentences with the unit.
    """

    section: str
    name: str
    type: str
    default: Any
    meaning: str


SECTIONS: tuple[str, ...] = (
    "study",
    "solver",
    "rig",
    "parameters",
    "targets",
    "measurements",
    "constraints",
    "preferences",
    "model",
    "budget",
    "design",
    "cluster",
)
"""The sections a study file may have, in the order the reference lists them."""

_K = StudyKey
# fmt: off
KEYS: tuple[StudyKey, ...] = (
    _K("study", "name", "string", REQUIRED,
       "The study's name: 1–64 letters, digits, `_`, `.` or `-`. It names the Optuna "
       "studies (`<name>/verify`, `<name>/calibrate/<model>`) and the default storage "
       "file `<name>.db` next to the study file."),
    _K("study", "seed", "integer ≥ 0", 0,
       "Seed of every random choice (designs, searches); the same seed gives the same runs."),
    _K("study", "storage", "string (URL)", None,
       "Optuna storage URL (`sqlite:///…`, `journal:///…`, `postgresql://…`); "
       "default: an SQLite file next to the study file. `--storage` overrides it."),
    _K("solver", "kind", "string", "builtin",
       "The full solver: `builtin` (the rod model, in-process), `calculix` (3-D finite "
       "elements with `ccx`) or `lsdyna` (your own keyword deck)."),
    _K("solver", "multi_fidelity", "boolean", True,
       "With an external solver, search the built-in solver corrected towards it and ask "
       "the external solver only to verify and to teach the correction. No effect on "
       "`builtin`."),
    _K("parameters", "ecoat_gpa", "table", "the paper's range",
       "Young's modulus of the coat [GPa]: `{ low = 0.5, high = 4.0, log = true }`."),
    _K("parameters", "scoat_gpa", "table", "the paper's range",
       "Yield stress of the coat [GPa]: `{ low = 0.05, high = 0.4, log = true }`."),
    _K("parameters", "tcoat_mm", "table", "the paper's range",
       "Thickness of each coat layer [mm]: `{ low = 0.01, high = 0.1, log = true }`."),
    _K("parameters.*", "low", "number > 0", REQUIRED, "Lower bound, in the parameter's unit."),
    _K("parameters.*", "high", "number > 0", REQUIRED, "Upper bound, in the parameter's unit."),
    _K("parameters.*", "log", "boolean", True, "Search the range on a logarithmic scale."),
    _K("parameters.*", "unit", "string", "the parameter's",
       "Must be the unit the name says (`GPa`, `mm`); convert the bounds otherwise."),
    _K("targets", "f60_n", "number > 0", None,
       "The measured force at 60° of rotation [N] that `surrogate run` identifies the "
       "coating against. A study needs `f60_n`, `[measurements] file`, or both."),
    _K("targets", "tolerance", "number in (0, 1)", 0.01,
       "Relative tolerance on F60: a verified point meets the target when "
       "|F60 − target| ≤ tolerance · target."),
    _K("targets", "measurements", "string (path)", None,
       "Older spelling of `[measurements] file`, still read."),
    _K("measurements", "file", "string (path)", None,
       "Measured curves in long CSV format (`test_id, angle_deg, force_n` plus condition "
       "columns), relative to the study file and inside the project folder."),
    _K("measurements", "noise_n", "number > 0", None,
       "The measurement noise σ [N]. Default: the pooled scatter of replicate tests "
       "(tests with the same conditions); needed when there are none."),
    _K("measurements", "delimiter", '","   ";"   or "\\t"', None,
       "Between columns. Default: detected in each file (the one that splits the header "
       "and every line into the same number of columns)."),
    _K("measurements", "decimal", '"." or ","', None,
       "The decimal mark. Default: detected (`,` only where no `.` decimals appear and "
       "the delimiter is not `,`)."),
    _K("measurements", "encoding", "string", "utf-8",
       "The files' text encoding (a UTF-8 byte-order mark is skipped)."),
    _K("measurements", "force_unit", '"N", "mN", "kN", "gf", "kgf" or "lbf"', None,
       "Unit of the force column. Default: the unit its name states (`force_mn`, "
       "`Force [mN]`), else N."),
    _K("measurements", "angle_unit", '"deg" or "rad"', None,
       "Unit of the angle column. Default: the unit its name states, else degrees."),
    _K("measurements", "columns", "table of strings", {},
       "The file's header for each product column, e.g. `{ force_n = \"Force [mN]\" }`; "
       "given, other columns are read only if named in the product's style."),
    _K("measurements", "conditions", "string (path)", None,
       "A table of each test's conditions, keyed by `test_id` or by `file` (for one file "
       "per test: `file` is then a glob such as `\"tests/*.csv\"`)."),
    _K("measurements", "name_pattern", "string", None,
       "The fields a one-test file's name gives, e.g. `\"{test_id}_{direction}_{tension_n}N\"`."),
    _K("constraints", "theta_sat_deg_min", "number ≤ 90", 80.0,
       "The force must keep rising at least until this rotation [deg] (θsat ≥ it)."),
    _K("constraints", "tcoat_max_fraction_of_thickness", "number < 0.5", 0.1,
       "Tcoat ≤ this fraction of the webbing thickness (0.1: < 10 % of 1.2 mm)."),
    _K("preferences", "order", "list of parameter names", ["tcoat_mm", "scoat_gpa"],
       "Among equally good points prefer lower values of these, the first first."),
    _K("model", "effects", "list of effect names", [],
       "The physical effects the calibrated model includes (built-in or a plug-in's, "
       "`--plugin`); `--effect` overrides it. `run`, `worker` and `doe --run` refuse a "
       "study that names any."),
    _K("budget", "initial_samples", "integer ≥ 3", 5,
       "Full-solver runs of the main job's initial design (Latin hypercube)."),
    _K("budget", "max_solver_calls", "integer ≥ 1", 30,
       "Cap on the main job's full-solver runs (`--budget` overrides it); at least "
       "`initial_samples` unless the built-in solver is an external solver's prior."),
    _K("budget", "candidates_per_iteration", "integer ≥ 1", 1,
       "Points sent to the full solver per iteration of the main job (diverse when > 1)."),
    _K("budget", "surrogate_trials", "integer ≥ 10", 300,
       "Cheap evaluations of the surrogate per search (Optuna trials in `run`, a Sobol "
       "batch rounded up to a power of two in `calibrate`)."),
    _K("budget", "identifiability_runs", "integer ≥ 0", 3,
       "Full-solver runs after verification for the exact local sensitivities of F60 "
       "(on top of the cap; 0: use the surrogate's)."),
    _K("budget", "calibration_solver_calls", "integer ≥ 1", 200,
       "Cap on a calibration's full-solver runs (`calibrate --budget` overrides it)."),
    _K("design", "replicates", "integer 1–20", 2,
       "Specimens a recommended test gets (`surrogate next-test`)."),
    _K("design", "tension_n", "table { low, high, log }", None,
       "The end tension [N] the lab can set for the next test, e.g. `{ low = 0, high = 60 }`."),
    _K("design", "bending_length_mm", "table { low, high, log }", None,
       "The bending length [mm] the lab can set, e.g. `{ low = 5, high = 17.5 }` (each end "
       "a test the rig can run: 2 × the length ≤ `[rig] free_length_mm`)."),
    _K("design", "rate_deg_s", "table { low, high, log }", None,
       "The rotation rate [°/s] the lab can set, e.g. `{ low = 9, high = 900, log = true }`."),
    _K("design", "direction", "list of strings", None,
       'The directions the lab can cut, e.g. `["warp", "weft"]`.'),
    _K("design", "free_length_mm", "table { low, high, log }", None,
       "The free strip length [mm] the lab can set."),
    _K("design", "width_mm", "table { low, high, log }", None,
       "The specimen width [mm] the lab can set."),
    _K("cluster", "partition", "string", None,
       "The partition (or `a,b`) of `--launcher slurm`'s jobs. Default: the cluster's."),
    _K("cluster", "account", "string", None,
       "The account the jobs are charged to. Default: the user's default account."),
    _K("cluster", "time_limit_min", "integer ≥ 1", None,
       "One run's wall-time limit [min]; the worker gives its run back 60 s before it. "
       "Default: the partition's."),
    _K("cluster", "cores", "integer ≥ 1", 1,
       "Tasks of one run's job (`$SLURM_NTASKS` inside it: an MPP solver's ranks)."),
    _K("cluster", "memory_mb", "integer ≥ 1", None,
       "Memory of one run's job per node [MB]. Default: what the cluster gives a core."),
    _K("cluster", "max_jobs", "integer ≥ 1", 8,
       "The most worker jobs queued or running at once."),
    _K("cluster", "submit_options", "list of strings", [],
       "Extra options of the submit command (`sbatch`), after the product's."),
    _K("cluster", "job_name_prefix", "string", "surrogate-",
       "Starts every job's name (the planner finds its own jobs by it)."),
    _K("cluster", "modules", "list of strings", [],
       "Environment modules loaded (`module load`) before the worker starts."),
    _K("cluster", "setup", "list of strings", [],
       "Shell lines run before the worker starts (e.g. `source venv/bin/activate`)."),
)
# fmt: on
"""Every key of every section but ``[rig]`` and the solvers' own settings."""

SOLVER_SETTINGS: dict[str, str] = {
    "mesh": "CalculiX: `coarse` (tests, fixed increments of 1.125°) or `fine` (production).",
    "command": "The program and its arguments as a list (CalculiX: `ccx`; LS-DYNA: also "
    "`SURROGATE_LSDYNA_COMMAND`; `i=main.k` is appended). Not part of a run's identity.",
    "timeout_s": "Seconds an attempt may take before the solver and its process group are "
    "killed. Not part of a run's identity.",
    "threads": "OpenMP threads of `ccx`. Not part of a run's identity.",
    "keep_workdir": "Keep each run's temporary working folder (for debugging a deck).",
    "workdir_root": "Where the working folders go (default: the system's temporary folder); "
    "relative to the study file.",
    "template": "LS-DYNA: your keyword deck of the bending test, relative to the study file.",
    "fill": "LS-DYNA: `parameter` (set `ECOAT`, `SCOAT`, `TCOAT` in `*PARAMETER` cards) or "
    "`seatbelt_card` (write card 3 of every `*MAT_SEATBELT_2D`).",
    "seatbelt_card": "LS-DYNA: the card of `*MAT_SEATBELT_2D` that holds the coating fields "
    "(default 3), if your manual revision differs.",
    "units": "LS-DYNA: the deck's units, `mm-N-s` (MPa), `mm-kg-ms` (GPa, kN) or `m-kg-s` (Pa).",
    "contact": "LS-DYNA: the `rcforc` interface id of the probe contact.",
    "rotation_node": "LS-DYNA: read the fixture rotation from this node in `nodout` (default: "
    "a linear ramp over `*CONTROL_TERMINATION` ENDTIM).",
    "template_sha256": "LS-DYNA: set by the loader to the template's content hash, so an "
    "edited template never reuses a cached run; do not write it.",
}
"""The meaning of each solver setting that some solver's ``settings_keys`` allows."""


def keys(section: str) -> tuple[str, ...]:
    """The keys allowed in ``section`` (``""``: the sections of the file itself)."""
    if section == "":
        return SECTIONS
    if section == "rig":
        return tuple(field.name for field in dataclasses.fields(Rig))
    if section == "parameters":
        return COATING_PARAMETERS
    return tuple(key.name for key in KEYS if key.section == section)


def rig_keys() -> tuple[StudyKey, ...]:
    """The ``[rig]`` keys: :class:`Rig`'s fields, their defaults, their docstring meanings."""
    meanings = _numpydoc_parameters(Rig.__doc__ or "")
    return tuple(
        StudyKey(
            "rig", field.name, _type_name(field.type), field.default, meanings.get(field.name, "")
        )
        for field in dataclasses.fields(Rig)
    )


def _type_name(annotation: Any) -> str:
    text = str(annotation)
    return {"float": "number", "float | None": "number or absent", "int": "integer"}.get(text, text)


def _numpydoc_parameters(doc: str) -> dict[str, str]:
    """``name : type`` entries of a numpydoc Parameters section → their text, one line."""
    entries: dict[str, str] = {}
    current: str | None = None
    for line in doc.splitlines():
        match = re.match(r"^\s{4}(\w+) : ", line)
        if match:
            current = match.group(1)
            entries[current] = ""
        elif current is not None and line.startswith(" " * 8):
            entries[current] = f"{entries[current]} {line.strip()}".strip()
        elif line.strip() == "" and current is not None:
            continue
    return entries
