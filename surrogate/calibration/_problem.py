"""The calibration problem: parameters, condition groups, measured points.

What ``calibrate``, ``compare`` and ``diagnose`` share about one model against one
set of measured curves: the parameter space (the coating and each enabled
effect's ``effect.param``), the *condition groups* (tests whose conditions the
model cannot tell apart — replicates, or a ``direction`` no enabled effect reads —
share one solver run per parameter point), the measured points, and the misfit
(measured minus model at every measured point; the model curve is the solver's on
whole degrees, interpolated to the measured angles). Also: each run's surrogate
inputs (:func:`surrogate.solvers.state_features` of its model state), the coat's
section, the study's measurements and noise level (:func:`load_calibration`), and
the checks of the commands' options.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InputDataError
from ..effects import ModelState, check_effects, get_effect, load_plugin
from ..physics import bending_stiffness, plastic_moment
from ..solvers import model_state_of, state_features
from ..solvers._batch import solver_inputs
from ..study._conditions import CONDITIONS, RIG_CONDITIONS
from ..study._measurements import MeasurementSet, load_measurements
from ..study._space import ParameterSpace, ParameterSpec
from ..study._spec import StudySpec, load_study
from ..study._units import gpa_to_mpa

__all__ = [
    "RIG_CONDITIONS",
    "CalibrationProblem",
    "calibration_study_name",
    "coat_section",
    "load_calibration",
    "model_label",
]


def model_label(effects: Sequence[str]) -> str:
    """A model's name: ``base`` or its effects joined by ``+`` (sorted)."""
    return "+".join(sorted(effects)) if effects else "base"


def calibration_study_name(spec: StudySpec, effects: Sequence[str]) -> str:
    return f"{spec.name}/calibrate/{model_label(effects)}"


class CalibrationProblem:
    """Parameters, condition groups and measured points of one calibration.

    Parameters
    ----------
    spec : StudySpec
        The study (coating ranges, rig, solver).
    data : MeasurementSet
        The measured curves.
    effects : sequence of str
        Enabled effects; their parameters are calibrated as ``effect.param``.
    tests : sequence, optional
        Use only these tests (the diagnosis leaves one out).
    """

    def __init__(
        self,
        spec: StudySpec,
        data: MeasurementSet,
        effects: Sequence[str] = (),
        *,
        tests: Sequence[Any] | None = None,
    ) -> None:
        self.spec = spec
        self.data = data
        self.effects = tuple(sorted(set(effects)))
        specs = list(spec.space.parameters)
        reads: set[str] = set(RIG_CONDITIONS)
        for name in self.effects:
            effect = get_effect(name)
            reads.update(effect.reads)
            for p in effect.parameters:
                specs.append(
                    ParameterSpec(f"{name}.{p.name}", p.low, p.high, log=p.log, unit=p.unit)
                )
        self.space = ParameterSpace.of(specs)
        # where each parameter goes: (None, name) of the coating, (effect, param) of an effect
        self._slots = tuple(
            (None, name) if "." not in name else tuple(name.split(".", 1))
            for name in self.space.names
        )
        self.conditions = tuple(
            c for c in (*CONDITIONS, *data.covariates) if c in reads and c in data.tests
        )
        test_ids = list(data.tests.test_id) if tests is None else list(tests)
        self.test_ids = test_ids
        self.groups: list[dict[str, Any]] = []
        group_of: dict[tuple[Any, ...], int] = {}
        self.test_group: list[int] = []
        table = data.tests.set_index("test_id")
        for test_id in test_ids:
            row = table.loc[test_id]
            conditions = {
                c: row[c] if isinstance(row[c], str) else float(row[c]) for c in self.conditions
            }
            key = tuple(conditions[c] for c in self.conditions)
            if key not in group_of:
                group_of[key] = len(self.groups)
                self.groups.append(conditions)
            self.test_group.append(group_of[key])
        self.angle_deg = np.arange(0.0, np.floor(spec.rig.max_angle_deg) + 1.0)
        self._points(data, test_ids)

    def _points(self, data: MeasurementSet, test_ids: list[Any]) -> None:
        angles, forces, group, test = [], [], [], []
        for index, test_id in enumerate(test_ids):
            a, f = data.curve(test_id)
            if a.max() > self.angle_deg[-1] or a.min() < 0.0:
                raise InputDataError(
                    f"test {test_id!r} has angles outside 0–{self.angle_deg[-1]:g}°, "
                    "the rig's range; raise [rig] max_angle_deg or drop those rows"
                )
            angles.append(a)
            forces.append(f)
            group.append(np.full(a.size, self.test_group[index]))
            test.append(np.full(a.size, index))
        angle = np.concatenate(angles)
        self.measured_n = np.concatenate(forces)
        self.point_group = np.concatenate(group)
        self.point_test = np.concatenate(test)
        self._lo = np.minimum(np.floor(angle).astype(int), self.angle_deg.size - 2)
        self._w = angle - self._lo
        self.point_angle_deg = angle
        self._count = np.bincount(self.point_test, minlength=len(test_ids))

    @property
    def n_points(self) -> int:
        return int(self.measured_n.size)

    # -- parameters ----------------------------------------------------------------------------
    def split(self, theta: Mapping[str, float]) -> tuple[dict[str, float], dict[str, Any]]:
        """Coating point and effects mapping of a parameter vector."""
        return self._split([theta[name] for name in self.space.names])

    def _split(self, values: Iterable[float]) -> tuple[dict[str, float], dict[str, Any]]:
        """:meth:`split` of the values in the space's order (the search's hot path: the
        names are not looked up again for each of its ~10⁵ model states)."""
        coating: dict[str, float] = {}
        effects: dict[str, dict[str, float]] = {name: {} for name in self.effects}
        for (effect, param), value in zip(self._slots, values, strict=True):
            (coating if effect is None else effects[effect])[param] = float(value)
        return coating, effects

    def off_value(self, name: str) -> float:
        """The value of effect parameter ``effect.param`` that switches its effect off
        (within its range): the effect's ``off``, or for a parameter whose off is NaN (the
        friction effect's μ) the rig's own value."""
        effect, param = name.split(".", 1)
        off = next(p.off for p in get_effect(effect).parameters if p.name == param)
        if math.isnan(off):
            off = self.spec.rig.friction
        spec = self.space[name]
        return min(max(off, spec.low), spec.high)

    # -- a verification: one point at every condition group -------------------------------------
    @property
    def runs_per_point(self) -> int:
        """Solver runs one parameter point costs: one at every condition group (``G``)."""
        return len(self.groups)

    def at_every_group(self, theta: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """The runs of one parameter point (a verification): ``theta`` repeated (G, p) and
        the groups ``0 … G−1``."""
        G = self.runs_per_point
        return np.repeat(np.asarray(theta)[None, :], G, axis=0), list(range(G))

    def one_verification(self) -> str:
        """What one verification is, in words: a run at each condition group."""
        G = self.runs_per_point
        return "a run at " + (
            f"each of the {G} condition groups" if G != 1 else "the one condition group"
        )

    def state(self, theta: np.ndarray, group: int) -> ModelState:
        """The model state the solver sees for parameter vector ``theta`` at a group."""
        coating, effects = self._split(theta)
        return model_state_of(
            coating["ecoat_gpa"],
            coating["scoat_gpa"],
            coating["tcoat_mm"],
            self.spec.rig,
            effects,
            self.groups[group],
        )

    def inputs(self, theta: Mapping[str, float], group: int) -> dict[str, Any]:
        coating, effects = self.split(theta)
        return solver_inputs(
            coating,
            self.spec.rig,
            solver=self.spec.solver,
            effects=effects,
            conditions=self.groups[group],
            solver_settings=self.spec.solver_settings,
        )

    # -- misfit --------------------------------------------------------------------------------
    def model_at_points(self, curves: np.ndarray) -> np.ndarray:
        """Model force at every measured point (P,) from (G, A) curves on whole degrees,
        or at every point of each of (m, G, A) curve sets (m, P): linear between the
        two whole degrees around each measured angle."""
        g, lo = self.point_group, self._lo
        return curves[..., g, lo] * (1.0 - self._w) + curves[..., g, lo + 1] * self._w

    def residuals(self, curves: np.ndarray) -> np.ndarray:
        """Measured minus model at every measured point."""
        return self.measured_n - self.model_at_points(curves)

    def rmse(self, curves: np.ndarray) -> float:
        return float(np.sqrt(np.mean(self.residuals(curves) ** 2)))

    def rmse_per_test(self, curves: np.ndarray) -> dict[str, float]:
        r2 = np.bincount(self.point_test, self.residuals(curves) ** 2, len(self.test_ids))
        rms = np.sqrt(r2 / self._count)
        return {str(t): float(v) for t, v in zip(self.test_ids, rms, strict=True)}

    def batch_rmse(self, curves: np.ndarray) -> np.ndarray:
        """RMSE of each of (m, G, A) curve sets."""
        residual = self.measured_n - self.model_at_points(curves)
        return np.sqrt(np.mean(residual**2, axis=1))

    def features(self, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
        """Surrogate inputs (n, f) of parameter vectors ``X`` (n, p) at condition ``groups``
        (n,): :func:`state_features` of each run's model state."""
        return np.array(
            [
                state_features(self.state(x, int(g)))
                for x, g in zip(np.atleast_2d(X), groups, strict=True)
            ]
        )


def coat_section(params: Mapping[str, float], thickness_mm: float) -> tuple[float, float]:
    """Bending stiffness D [N·mm] and plastic moment Mp [N] per unit width of a coating
    given in the paper's units (``ecoat_gpa``, ``scoat_gpa``, ``tcoat_mm``)."""
    tcoat = params["tcoat_mm"]
    return (
        bending_stiffness(gpa_to_mpa(params["ecoat_gpa"]), tcoat, thickness_mm),
        plastic_moment(gpa_to_mpa(params["scoat_gpa"]), tcoat, thickness_mm),
    )


def load_calibration(
    study: str | Path | StudySpec,
    effects: Sequence[str] | None,
    plugins: Sequence[str],
) -> tuple[StudySpec, MeasurementSet, tuple[str, ...], float]:
    """The study, its measurements, the model's effects and the noise level [N].

    Plug-ins are imported first; unknown effects, a study without measurements
    and a noise level neither stated nor estimable fail here, before anything is
    written.
    """
    for module in plugins:
        load_plugin(module)
    spec = study if isinstance(study, StudySpec) else load_study(study)
    check_effects(spec.effects)  # unknown names fail here, before anything is written
    if spec.measurements_file is None:
        raise InputDataError(
            f"study {spec.name!r} has no [measurements] file; add one to calibrate against curves"
        )
    data = load_measurements(spec.measurements_file, file_format=spec.measurement_format)
    chosen = tuple(spec.effects) if effects is None else check_effects(effects)
    noise = spec.noise_n if spec.noise_n is not None else data.noise_n
    if noise is None:
        raise InputDataError(
            f"{spec.measurements_file}: no replicate tests to estimate the noise; "
            "add [measurements] noise_n (N) to the study"
        )
    return spec, data, chosen, float(noise)
