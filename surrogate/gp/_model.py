"""Gaussian-process surrogates of F60, θsat and the force–rotation curve.

- F60 is modelled through ``log F60`` (forces span two decades; relative
  errors matter); its prediction is ``exp(μ)`` with the 95 % interval
  ``exp(μ ± 1.96σ)``, and its reported standard deviation ``F60·σ``.
- θsat is modelled as it is, with a noise floor of its 1° grid
  (``1/√12`` degrees); predictions are clipped to the tested range, where the
  definition caps it.
- The curve is modelled on a reduced basis: principal components of the
  training curves' logarithm (forces span decades, and on a log scale a curve
  is its level plus a shape), enough for 99.99 % of their variance
  (``curve_variance``; at most 12 components, :class:`PrincipalBasis`), one GP
  per score; the force at 0° is zero by definition and is not modelled. The
  sharp knee where a curve saturates is what the basis truncates: a few per cent
  there, well under 1 % elsewhere.

All three share the features of :class:`FeatureMap`. Follows scikit-learn's
estimator contract: ``__init__`` stores arguments, ``fit`` validates and returns
``self``, learned state ends in ``_``, ``predict(X, return_std=False)``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InputDataError
from .._io import atomic_write_text
from .._pool import one_blas_thread_within
from ..study._space import ParameterSpace
from ._basis import PrincipalBasis
from ._features import FeatureMap
from ._output import OutputGP

__all__ = ["CoatingSurrogate", "cross_validation_table"]

FORMAT = "webbing-surrogate/gp"
THETA_GRID_SD_DEG = 1.0 / np.sqrt(12.0)
F60_RELATIVE_SD = 1e-3  # the solver's discretisation error is ~3e-4
MAX_CURVE_COMPONENTS = 12


class CoatingSurrogate:
    """GP surrogates of one study's outputs over its parameter space.

    Parameters
    ----------
    space : ParameterSpace
        The inputs, in column order of ``X``.
    nu : float
        Smoothness of the Matérn kernels.
    n_restarts : int
        Restarts of the hyperparameter optimiser.
    seed : int or None
        Seed of those restarts.
    max_angle_deg : float
        End of the tested range (θsat's cap).
    curve_variance : float
        Fraction of the curves' variance kept by the basis.
    """

    def __init__(
        self,
        space: ParameterSpace,
        *,
        nu: float = 1.5,
        n_restarts: int = 5,
        seed: int | None = 0,
        max_angle_deg: float = 90.0,
        curve_variance: float = 0.9999,
    ) -> None:
        self.space = space
        self.nu = nu
        self.n_restarts = n_restarts
        self.seed = seed
        self.max_angle_deg = max_angle_deg
        self.curve_variance = curve_variance

    # -- fitting ---------------------------------------------------------------------------
    @one_blas_thread_within
    def fit(
        self,
        X: np.ndarray,
        f60_n: np.ndarray,
        theta_sat_deg: np.ndarray,
        curves: np.ndarray | None = None,
        angle_deg: np.ndarray | None = None,
    ) -> CoatingSurrogate:
        """Fit on ``X`` (n, d) raw inputs; ``curves`` (n, m) at ``angle_deg`` (m,)."""
        X, f60, theta = self._validate(X, f60_n, theta_sat_deg)
        self.features_ = FeatureMap(self.space)
        Z = self.features_.transform(X)
        self.X_train_, self.f60_train_, self.theta_train_ = X, f60, theta
        self.f60_gp_ = self._gp(F60_RELATIVE_SD).fit(Z, np.log(f60))
        self.theta_gp_ = self._gp(THETA_GRID_SD_DEG).fit(Z, theta)
        self.curves_train_: np.ndarray | None = None
        if curves is not None:
            self._fit_curves(Z, np.asarray(curves, dtype=float), np.asarray(angle_deg, float))
        return self

    def _gp(self, noise_sd: float) -> OutputGP:
        return OutputGP(nu=self.nu, noise_sd=noise_sd, n_restarts=self.n_restarts, seed=self.seed)

    def _validate(self, X, f60, theta):
        X = np.atleast_2d(np.asarray(X, dtype=float))
        f60 = np.asarray(f60, dtype=float)
        theta = np.asarray(theta, dtype=float)
        if X.shape[1] != len(self.space):
            raise InputDataError(
                f"X has {X.shape[1]} columns, the space has {len(self.space)} "
                f"({', '.join(self.space.names)})"
            )
        if not (X.shape[0] == f60.size == theta.size):
            raise InputDataError("X, f60_n and theta_sat_deg need the same number of rows")
        if X.shape[0] < 3:
            raise InputDataError(f"a surrogate needs at least 3 successful runs, got {X.shape[0]}")
        for name, values in (("X", X), ("f60_n", f60), ("theta_sat_deg", theta)):
            if not np.all(np.isfinite(values)):
                raise InputDataError(f"{name} contains NaN or inf; drop failed runs first")
        if np.any(f60 <= 0.0):
            raise InputDataError("f60_n must be > 0 to be modelled on a log scale")
        return X, f60, theta

    def _fit_curves(self, Z: np.ndarray, curves: np.ndarray, angles: np.ndarray) -> None:
        if curves.shape != (Z.shape[0], angles.size) or not np.all(np.isfinite(curves)):
            raise InputDataError("curves must be finite, one row per run, one column per angle")
        loaded = angles > 0.0
        if np.any(curves[:, loaded] <= 0.0):
            raise InputDataError("curve forces must be > 0 at every angle > 0")
        log_curves = np.log(curves[:, loaded])
        self.curve_pca_ = PrincipalBasis.fit(
            log_curves, variance=self.curve_variance, max_components=MAX_CURVE_COMPONENTS
        )
        self.angle_deg_, self.curves_train_ = angles, curves
        scores = self.curve_pca_.project(log_curves)
        self.curve_gps_ = [
            self._gp(0.0).fit(Z, scores[:, j]) for j in range(self.curve_pca_.n_components)
        ]

    @property
    def curve_mean_(self) -> np.ndarray:
        """Mean log-curve (m_loaded,) of the basis."""
        return self.curve_pca_.mean

    @property
    def curve_basis_(self) -> np.ndarray:
        """Principal components (k, m_loaded) of the log-curves."""
        return self.curve_pca_.basis

    # -- prediction ------------------------------------------------------------------------
    @one_blas_thread_within
    def predict(self, X: np.ndarray, return_std: bool = False) -> dict[str, np.ndarray]:
        """``{"f60_n", "theta_sat_deg"}`` (and ``…_std``) at ``X`` (n, d)."""
        Z = self._features(X)
        mu, sd = self.f60_gp_.predict(Z, return_std=True)
        theta, theta_sd = self.theta_gp_.predict(Z, return_std=True)
        out = {"f60_n": np.exp(mu), "theta_sat_deg": np.clip(theta, 0.0, self.max_angle_deg)}
        if return_std:
            out["f60_n_std"] = np.exp(mu) * sd
            out["theta_sat_deg_std"] = theta_sd
            out["log_f60_std"] = sd
        return out

    @one_blas_thread_within
    def predict_curve(self, X: np.ndarray, return_std: bool = False):
        """Predicted curves (n, m) at :attr:`angle_deg_` (and their std)."""
        if self.curves_train_ is None:
            raise InputDataError("this surrogate was fitted without curves")
        Z = self._features(X)
        means, variances = [], []
        for gp in self.curve_gps_:
            m, s = gp.predict(Z, return_std=True)
            means.append(m)
            variances.append(s**2)
        scores, var = np.column_stack(means), np.column_stack(variances)
        loaded = self.angle_deg_ > 0.0
        curve = np.zeros((scores.shape[0], self.angle_deg_.size))
        curve[:, loaded] = np.exp(self.curve_pca_.reconstruct(scores))
        if return_std:
            std = np.zeros_like(curve)
            std[:, loaded] = curve[:, loaded] * np.sqrt(self.curve_pca_.reconstruct_variance(var))
            return curve, std
        return curve

    def _features(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != len(self.space):
            raise InputDataError(f"points need the columns {', '.join(self.space.names)}")
        if not np.all(np.isfinite(X)):
            raise InputDataError("points contain NaN or inf")
        return self.features_.transform(X)

    # -- cross-validation ------------------------------------------------------------------
    @one_blas_thread_within
    def cross_validate(self) -> dict[str, dict[str, float]]:
        """Leave-one-out error and 95 %-interval coverage of each output."""
        mu, sd = self.f60_gp_.loo()
        f60 = self.f60_train_
        theta_mu, theta_sd = self.theta_gp_.loo()
        theta_pred = np.clip(theta_mu, 0.0, self.max_angle_deg)
        theta = self.theta_train_
        return {
            "f60_n": {
                "loo_median_rel_err": float(np.median(np.abs(np.exp(mu) / f60 - 1.0))),
                "loo_mae": float(np.mean(np.abs(np.exp(mu) - f60))),
                "coverage95": float(np.mean(np.abs(np.log(f60) - mu) <= 1.96 * sd)),
            },
            "theta_sat_deg": {
                "loo_median_rel_err": float(
                    np.median(np.abs(theta_pred - theta) / np.maximum(theta, 1.0))
                ),
                "loo_mae": float(np.mean(np.abs(theta_pred - theta))),
                "coverage95": float(np.mean(np.abs(theta - theta_pred) <= 1.96 * theta_sd)),
            },
        }

    # -- persistence (data, never pickle) --------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "format": FORMAT,
            "version": 1,
            "space": self.space.to_dict(),
            "settings": {
                "nu": self.nu,
                "n_restarts": self.n_restarts,
                "seed": self.seed,
                "max_angle_deg": self.max_angle_deg,
                "curve_variance": self.curve_variance,
            },
            "train": {
                "X": self.X_train_.tolist(),
                "f60_n": self.f60_train_.tolist(),
                "theta_sat_deg": self.theta_train_.tolist(),
            },
            "outputs": {"f60_n": self.f60_gp_.to_dict(), "theta_sat_deg": self.theta_gp_.to_dict()},
            "cross_validation": self.cross_validate(),
        }
        if self.curves_train_ is not None:
            data["train"]["angle_deg"] = self.angle_deg_.tolist()
            data["train"]["curves"] = self.curves_train_.tolist()
            data["outputs"]["curve"] = {
                "mean": self.curve_mean_.tolist(),
                "basis": self.curve_basis_.tolist(),
                "scores": [gp.to_dict() for gp in self.curve_gps_],
            }
        return data

    def save(self, path: str | Path) -> Path:
        return atomic_write_text(path, json.dumps(self.to_json()) + "\n")

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> CoatingSurrogate:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise InputDataError(f"not a surrogate model file (format {FORMAT!r} expected)")
        try:
            return cls._from_json(data)
        except (KeyError, TypeError, ValueError) as error:
            if isinstance(error, InputDataError):
                raise
            raise InputDataError(
                f"surrogate model file is incomplete or damaged ({error!r})"
            ) from None

    @classmethod
    def _from_json(cls, data: dict[str, Any]) -> CoatingSurrogate:
        model = cls(ParameterSpace.from_dict(data["space"]), **data["settings"])
        train = data["train"]
        model.features_ = FeatureMap(model.space)
        model.X_train_ = np.asarray(train["X"], dtype=float)
        model.f60_train_ = np.asarray(train["f60_n"], dtype=float)
        model.theta_train_ = np.asarray(train["theta_sat_deg"], dtype=float)
        Z = model.features_.transform(model.X_train_)
        outputs = data["outputs"]
        model.f60_gp_ = OutputGP.from_dict(outputs["f60_n"], Z, np.log(model.f60_train_))
        model.theta_gp_ = OutputGP.from_dict(outputs["theta_sat_deg"], Z, model.theta_train_)
        model.curves_train_ = None
        if "curve" in outputs:
            model.angle_deg_ = np.asarray(train["angle_deg"], dtype=float)
            curves = np.asarray(train["curves"], dtype=float)
            model.curves_train_ = curves
            model.curve_pca_ = PrincipalBasis(
                np.asarray(outputs["curve"]["mean"], dtype=float),
                np.asarray(outputs["curve"]["basis"], dtype=float),
            )
            scores = model.curve_pca_.project(np.log(curves[:, model.angle_deg_ > 0.0]))
            model.curve_gps_ = [
                OutputGP.from_dict(item, Z, scores[:, j])
                for j, item in enumerate(outputs["curve"]["scores"])
            ]
        return model

    @classmethod
    def load(cls, path: str | Path) -> CoatingSurrogate:
        path = Path(path)
        if not path.exists():
            raise InputDataError(f"model file {path} does not exist; check the path")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise InputDataError(f"model file {path} is not valid JSON ({error})") from None
        return cls.from_json(data)


def cross_validation_table(cv: dict[str, dict[str, float]]) -> str:
    """The CV figures as a small text table."""
    lines = [f"{'output':<15} {'LOO median rel err':>19} {'LOO MAE':>10} {'95% coverage':>13}"]
    for name, row in cv.items():
        unit = "N" if name == "f60_n" else "deg"
        lines.append(
            f"{name:<15} {100 * row['loo_median_rel_err']:>18.2f}% "
            f"{row['loo_mae']:>6.3g} {unit:<3} {100 * row['coverage95']:>12.0f}%"
        )
    return "\n".join(lines)
