"""One scalar output modelled by a scikit-learn Gaussian process.

Notations
---------
Z       (n, k) features (see ``_features``), y (n,) targets.
yn      (y − mean) / std with the training set's mean and std: standardised
        once, so leave-one-out and a hand-made split see the same targets.
K       kernel matrix of the training features, including the noise term.

The kernel is ``C · Matern(ARD, ν) + White``; the white noise has a floor (the
resolution of the output, e.g. θsat's 1° grid) so the GP never claims more
precision than the solver gives. Leave-one-out uses the closed form
(Rasmussen & Williams 2006, eq. 5.12) with the fitted hyperparameters:
``μ_i = yn_i − [K⁻¹yn]_i / [K⁻¹]_ii``, ``σ²_i = 1 / [K⁻¹]_ii``.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from scipy.linalg import cho_solve
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process.kernels import ConstantKernel, Kernel, Matern, WhiteKernel

from ._regressor import Regressor

__all__ = ["OutputGP"]


def _kernel(n_features: int, nu: float, noise_floor: float) -> Kernel:
    length = np.full(n_features, 0.5)
    if n_features >= 4:
        length[3] = 20.0  # log(Tcoat) matters little once D, Mp and S/E are given
    return ConstantKernel(1.0, (1e-3, 1e3)) * Matern(
        length_scale=length, length_scale_bounds=(1e-2, 1e3), nu=nu
    ) + WhiteKernel(
        max(2.0 * noise_floor, 1e-8), (max(noise_floor, 1e-10), max(100.0 * noise_floor, 1e-6))
    )


class OutputGP:
    """GP of one output with standardised targets and closed-form LOO."""

    def __init__(
        self, *, nu: float = 1.5, noise_sd: float = 0.0, n_restarts: int = 5, seed: int | None = 0
    ) -> None:
        self.nu = nu
        self.noise_sd = noise_sd
        self.n_restarts = n_restarts
        self.seed = seed

    def fit(self, features: np.ndarray, y: np.ndarray) -> OutputGP:
        y = np.asarray(y, dtype=float)
        self.y_mean_ = float(np.mean(y))
        std = float(np.std(y))
        self.y_std_ = std if std > 0.0 else 1.0
        self.noise_floor_ = (self.noise_sd / self.y_std_) ** 2
        kernel = _kernel(features.shape[1], self.nu, self.noise_floor_)
        self._fit_gp(features, y, kernel, optimise=True)
        return self

    def _fit_gp(
        self, features: np.ndarray, y: np.ndarray, kernel: Kernel, *, optimise: bool
    ) -> None:
        gp = Regressor(
            kernel=kernel,
            normalize_y=False,
            optimizer="fmin_l_bfgs_b" if optimise else None,
            n_restarts_optimizer=self.n_restarts if optimise else 0,
            random_state=self.seed,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # bounds hit: reported by CV
            gp.fit(features, (y - self.y_mean_) / self.y_std_)
        self.gp_ = gp

    def predict(self, features: np.ndarray, return_std: bool = False):
        if return_std:
            mean, std = self.gp_.predict(features, return_std=True)
            return mean * self.y_std_ + self.y_mean_, std * self.y_std_
        return self.gp_.predict(features) * self.y_std_ + self.y_mean_

    def loo(self) -> tuple[np.ndarray, np.ndarray]:
        """Leave-one-out mean and standard deviation of every training target."""
        gp = self.gp_
        inverse = cho_solve((gp.L_, True), np.eye(gp.L_.shape[0]))
        diag = np.diag(inverse)
        mean = gp.y_train_ - gp.alpha_ / diag
        return mean * self.y_std_ + self.y_mean_, np.sqrt(1.0 / diag) * self.y_std_

    @property
    def kernel_(self) -> Kernel:
        return self.gp_.kernel_

    def to_dict(self) -> dict[str, Any]:
        return {
            "nu": self.nu,
            "noise_sd": self.noise_sd,
            "y_mean": self.y_mean_,
            "y_std": self.y_std_,
            "theta": self.gp_.kernel_.theta.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], features: np.ndarray, y: np.ndarray) -> OutputGP:
        """Rebuild with the stored hyperparameters (refit, no optimisation)."""
        model = cls(nu=float(data["nu"]), noise_sd=float(data["noise_sd"]), n_restarts=0)
        model.y_mean_ = float(data["y_mean"])
        model.y_std_ = float(data["y_std"])
        model.noise_floor_ = (model.noise_sd / model.y_std_) ** 2
        template = _kernel(features.shape[1], model.nu, model.noise_floor_)
        kernel = template.clone_with_theta(np.asarray(data["theta"], dtype=float))
        model._fit_gp(features, np.asarray(y, dtype=float), kernel, optimise=False)
        return model
