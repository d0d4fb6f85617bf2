"""Inputs of the GP surrogates: physical coordinates of the coating.

The force curve of a coated strip depends on the coating almost only through
the bending stiffness ``D ≈ Ecoat·Tcoat·t²/2``, the plastic moment
``Mp ≈ Scoat·Tcoat·t`` and the yield strain ``Scoat/Ecoat`` (which sets where
the curve saturates); ``Tcoat`` alone shapes the short elastic–plastic
transition. So the three coating parameters become four features,
``log(E·T), log(S·T), log(S/E), log(T)``, each scaled to [0, 1] over the
parameter space. F60 is a min-like function of the first two with a kink
along the third: in these coordinates an ARD kernel can follow it with one
short length scale, where in ``(log E, log S, log T)`` the kink runs
diagonally. Measured by benchmarks/surrogate.py; other inputs (test
conditions, effect parameters) are scaled to [0, 1] as declared.
"""

from __future__ import annotations

import numpy as np

from ..study._space import COATING_PARAMETERS, ParameterSpace

__all__ = ["FeatureMap"]


class FeatureMap:
    """Map raw inputs ``(n, d)`` in ``space`` order to GP features ``(n, k)``."""

    def __init__(self, space: ParameterSpace) -> None:
        self.space = space
        names = space.names
        self.coating = all(name in names for name in COATING_PARAMETERS)
        self._coating_index = [names.index(n) for n in COATING_PARAMETERS] if self.coating else []
        self._other_index = [i for i in range(len(names)) if i not in self._coating_index]
        if self.coating:
            lo = np.log([space[n].low for n in COATING_PARAMETERS])
            hi = np.log([space[n].high for n in COATING_PARAMETERS])
            self._low = np.array([lo[0] + lo[2], lo[1] + lo[2], lo[1] - hi[0], lo[2]])
            self._high = np.array([hi[0] + hi[2], hi[1] + hi[2], hi[1] - lo[0], hi[2]])

    @property
    def n_features(self) -> int:
        return (4 if self.coating else 0) + len(self._other_index)

    @property
    def feature_names(self) -> list[str]:
        names = ["log_ecoat_tcoat", "log_scoat_tcoat", "log_scoat_over_ecoat", "log_tcoat"]
        return (names if self.coating else []) + [self.space.names[i] for i in self._other_index]

    def transform(self, values: np.ndarray) -> np.ndarray:
        values = np.atleast_2d(np.asarray(values, dtype=float))
        columns = []
        if self.coating:
            log_e, log_s, log_t = np.log(values[:, self._coating_index]).T
            raw = np.column_stack([log_e + log_t, log_s + log_t, log_s - log_e, log_t])
            columns.append((raw - self._low) / (self._high - self._low))
        for i in self._other_index:
            columns.append(self.space.parameters[i].to_unit(values[:, i])[:, None])
        return np.hstack(columns)
