"""``doe``, ``fit`` and ``predict``: sample sets and the GP surrogate."""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from .._errors import InputDataError
from .._io import atomic_write_text, check_output_file
from .._pool import one_blas_thread_within
from .._validate import check_seed
from ..effects import check_effects
from ..solvers._batch import evaluate_design
from ..study._rig import Rig
from ..study._samples import SampleSet, read_points
from ..study._space import PAPER_SPACE, ParameterSpace
from ..study._spec import StudySpec, load_study
from ._doe import make_design
from ._objective import refuse_model_effects

if TYPE_CHECKING:  # the GP (scikit-learn) loads with fit and predict, not with doe
    from ..gp import CoatingSurrogate

__all__ = ["DoeResult", "FitResult", "PredictResult", "doe", "fit", "fit_surrogate", "predict"]


@dataclass(frozen=True)
class DoeResult:
    """Keys of ``surrogate doe --json``.

    ``design`` is the design's kind and ``n_points`` its points; ``out`` the CSV
    written; ``ran`` whether the points were run (``--run``), ``n_ok`` and ``n_failed``
    the runs that gave a curve and those that failed (each a row with its reason),
    ``solver_calls`` the runs solved and ``cached`` those taken from the result cache.
    """

    design: str
    n_points: int
    out: str
    ran: bool
    n_ok: int
    n_failed: int
    solver_calls: int
    cached: int

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class FitResult:
    """Keys of ``surrogate fit --json``: the cross-validation of each output.

    ``f60_n`` and ``theta_sat_deg`` are the leave-one-out figures of each GP (its error
    and the coverage of its 95 % intervals); ``n_train`` the runs fitted; ``model`` the
    JSON file written (None without ``--out``).
    """

    f60_n: dict[str, float]
    theta_sat_deg: dict[str, float]
    n_train: int
    model: str | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PredictResult:
    """Keys of ``surrogate predict --json``.

    ``n_points`` is the points predicted; ``out`` the CSV written (None without
    ``--out``); ``predictions`` one row a point: the coating, F60 and θsat with their
    standard deviations.
    """

    n_points: int
    out: str | None
    predictions: list[dict[str, float]]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _study_or_none(
    study: str | Path | StudySpec | None, *, runs: bool, plugins: Sequence[str]
) -> StudySpec | None:
    """The study (its effects checked: runs of the bare coating refuse any), or None."""
    if study is None:
        return None
    spec = study if isinstance(study, StudySpec) else load_study(study)
    if runs:
        refuse_model_effects(spec, "surrogate doe --run")
    else:
        check_effects(spec.effects, plugins)
    return spec


@one_blas_thread_within
def doe(
    design: str = "lhs",
    *,
    n: int = 16,
    seed: int | None = None,
    study: str | Path | StudySpec | None = None,
    run: bool = False,
    jobs: int = 1,
    out: str | Path,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    points_file: str | Path | None = None,
    plugins: Sequence[str] = (),
) -> DoeResult:
    """Make a design (ranges from ``study`` or the paper's) and optionally run it.

    Without ``run`` the design points are written to ``out``; with ``run`` the
    full solver evaluates them and ``out`` is a sample set (plus curves and a
    JSON sidecar). Cache: ``cache_dir`` or ``.solver-cache/`` next to ``out``.
    ``points_file``: take the points from this CSV (a design of one's own, with
    the parameter columns) instead of generating them; ``design`` is then ``file``.
    ``plugins``: modules of effects the study's ``[model] effects`` name.
    """
    spec = _study_or_none(study, runs=run, plugins=plugins)
    space = spec.space if spec is not None else PAPER_SPACE
    rig = spec.rig if spec is not None else Rig()
    seed = check_seed(seed if seed is not None else (spec.seed if spec is not None else 0))
    out = check_output_file(out)
    if points_file is not None:
        design = "file"
        points = _read_design(points_file, space)
    else:
        points = make_design(design, space, n=n, seed=seed)
    if not run:
        buffer = io.StringIO()
        points.to_csv(buffer, index=False, float_format="%.10g")
        atomic_write_text(out, buffer.getvalue())
        return DoeResult(design, len(points), str(out), False, 0, 0, 0, 0)
    cache = Path(cache_dir) if cache_dir is not None else out.parent / ".solver-cache"
    samples = evaluate_design(
        points,
        space,
        rig=rig,
        solver=spec.solver if spec is not None else "builtin",
        solver_settings=spec.solver_settings if spec is not None else None,
        jobs=jobs,
        cache_dir=cache,
        progress=progress,
        meta={"design": design, "seed": seed},
    )
    samples.write(out)
    return _ran(design, len(points), out, samples)


def _ran(design: str, n_points: int, out: Path, samples: SampleSet) -> DoeResult:
    calls = int(samples.meta["solver_calls"])
    return DoeResult(
        design, n_points, str(out), True, len(samples.ok), samples.n_failed, calls, n_points - calls
    )


def _read_design(points_file: str | Path, space: ParameterSpace) -> pd.DataFrame:
    """A design of one's own: the parameter columns of a CSV, every value in its range."""
    points = read_points(points_file, space.names)
    outside = [n for n in space.names if not np.all(space[n].contains(points[n]))]
    if outside:
        raise InputDataError(
            f"{points_file}: column {outside[0]} has values outside "
            f"[{space[outside[0]].low:g}, {space[outside[0]].high:g}]; "
            "fix them or widen the study's range"
        )
    return points


def fit_surrogate(
    samples: SampleSet, *, seed: int = 0, with_curves: bool = True
) -> CoatingSurrogate:
    """A :class:`CoatingSurrogate` of the successful runs of ``samples``; its curve part
    only ``with_curves`` (the main loop's search reads F60 and θsat alone, and the
    curve's GPs, fitted independently, cost it two thirds of a fit)."""
    ok = samples.ok
    if len(ok) < 3:
        raise InputDataError(
            f"the sample set has {len(ok)} successful runs; a surrogate needs at least 3"
        )
    X = ok[list(samples.space.names)].to_numpy(dtype=float)
    curves = angles = None
    if with_curves and len(samples.curves):
        angles, curves = samples.curve_matrix(ok["run_id"].to_numpy())
    max_angle = float(angles[-1]) if angles is not None else 90.0
    from ..gp import CoatingSurrogate

    return CoatingSurrogate(samples.space, seed=seed, max_angle_deg=max_angle).fit(
        X,
        ok["f60_n"].to_numpy(dtype=float),
        ok["theta_sat_deg"].to_numpy(dtype=float),
        curves,
        angles,
    )


@one_blas_thread_within
def fit(
    samples: str | Path | SampleSet, *, out: str | Path | None = None, seed: int = 0
) -> FitResult:
    """Fit the surrogates to a sample set, cross-validate, and save as JSON."""
    check_seed(seed)
    sample_set = samples if isinstance(samples, SampleSet) else SampleSet.read(samples)
    if out is not None:
        check_output_file(out)
    model = fit_surrogate(sample_set, seed=seed)
    cv = model.cross_validate()
    if out is not None:
        model.save(out)
    return FitResult(
        cv["f60_n"], cv["theta_sat_deg"], len(sample_set.ok), None if out is None else str(out)
    )


@one_blas_thread_within
def predict(
    model: str | Path | CoatingSurrogate,
    points: str | Path | pd.DataFrame,
    *,
    out: str | Path | None = None,
) -> PredictResult:
    """Predict F60 and θsat (with standard deviations) at the points."""
    from ..gp import CoatingSurrogate

    if out is not None:
        check_output_file(out)
    surrogate = model if isinstance(model, CoatingSurrogate) else CoatingSurrogate.load(model)
    names = surrogate.space.names
    table = points.copy() if isinstance(points, pd.DataFrame) else read_points(points, names)
    if isinstance(points, pd.DataFrame):
        missing = [n for n in names if n not in table]
        if missing:
            raise InputDataError(f"points miss column(s) {', '.join(missing)}")
    _check_in_space(table, surrogate.space)
    pred = surrogate.predict(table[list(names)].to_numpy(dtype=float), return_std=True)
    for key in ("f60_n", "f60_n_std", "theta_sat_deg", "theta_sat_deg_std"):
        table[key] = pred[key]
    if out is not None:
        buffer = io.StringIO()
        table.to_csv(buffer, index=False, float_format="%.8g")
        atomic_write_text(out, buffer.getvalue())
    records = table[[*names, "f60_n", "f60_n_std", "theta_sat_deg", "theta_sat_deg_std"]]
    return PredictResult(len(table), None if out is None else str(out), records.to_dict("records"))


def _check_in_space(table: pd.DataFrame, space: ParameterSpace) -> None:
    for spec in space:
        values = table[spec.name].to_numpy(dtype=float)
        if np.any(values <= 0.0) and spec.log:
            raise InputDataError(f"column {spec.name} must be > 0")
