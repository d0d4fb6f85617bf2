"""Declared parameters and the coating space, in the paper's units.

Optimise and sample in the unit cube (log-scaled where declared), convert back
only at the edge (scikit-learn's ``Hyperparameter``, Optuna's ``FloatDistribution``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._errors import InputDataError
from .._validate import check_finite

__all__ = [
    "COATING_PARAMETERS",
    "DESIGNS",
    "PAPER_SPACE",
    "ParameterSpace",
    "ParameterSpec",
]

COATING_PARAMETERS = ("ecoat_gpa", "scoat_gpa", "tcoat_mm")
DESIGNS = ("factorial", "lhs", "sobol", "paper")
"""Designs of experiments offered (see ``_doe.make_design``)."""


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: ``low <= value <= high``, sampled on a log scale if ``log``."""

    name: str
    low: float
    high: float
    log: bool = False
    unit: str = ""

    def __post_init__(self) -> None:
        low = check_finite(f"{self.name}.low", self.low)
        high = check_finite(f"{self.name}.high", self.high)
        if not low < high:
            raise InputDataError(
                f"{self.name}: `low < high` must hold, but got low={low:g}, high={high:g}"
            )
        if self.log and low <= 0.0:
            raise InputDataError(
                f"{self.name}: a log-scaled parameter needs low > 0, got low={low:g}; "
                "set log = false or raise low"
            )
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def span(self) -> float:
        """The range in the sampled scale: ``log(high/low)`` if log-scaled, else ``high − low``."""
        return float(np.log(self.high) - np.log(self.low)) if self.log else self.high - self.low

    def to_unit(self, values: np.ndarray) -> np.ndarray:
        """Map values in ``[low, high]`` to ``[0, 1]`` (log-scaled if declared)."""
        values = np.asarray(values, dtype=float)
        if self.log:
            return (np.log(values) - np.log(self.low)) / self.span
        return (values - self.low) / self.span

    def from_unit(self, unit: np.ndarray | float) -> np.ndarray:
        """Inverse of :meth:`to_unit`."""
        unit = np.asarray(unit, dtype=float)
        if self.log:
            return np.exp(np.log(self.low) + unit * self.span)
        return self.low + unit * self.span

    def contains(self, values: np.ndarray, *, rtol: float = 1e-9) -> np.ndarray:
        span = self.high - self.low
        values = np.asarray(values, dtype=float)
        return (values >= self.low - rtol * span) & (values <= self.high + rtol * span)

    def to_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "low": self.low,
            "high": self.high,
            "log": self.log,
            "unit": self.unit,
        }


@dataclass(frozen=True)
class ParameterSpace:
    """An ordered tuple of :class:`ParameterSpec`."""

    parameters: tuple[ParameterSpec, ...]

    def __post_init__(self) -> None:
        names = [p.name for p in self.parameters]
        if len(set(names)) != len(names):
            raise InputDataError(f"parameter names must be unique, got {names}")

    @classmethod
    def of(cls, specs: Iterable[ParameterSpec]) -> ParameterSpace:
        return cls(tuple(specs))

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)  # once: the search asks ~10⁵ times

    def __iter__(self) -> Iterator[ParameterSpec]:
        return iter(self.parameters)

    def __len__(self) -> int:
        return len(self.parameters)

    def __getitem__(self, name: str) -> ParameterSpec:
        for spec in self.parameters:
            if spec.name == name:
                return spec
        raise KeyError(name)

    def to_unit(self, values: np.ndarray) -> np.ndarray:
        """(n, d) values → (n, d) unit-cube coordinates."""
        values = np.atleast_2d(np.asarray(values, dtype=float))
        return np.column_stack([p.to_unit(values[:, i]) for i, p in enumerate(self.parameters)])

    def from_unit(self, unit: np.ndarray) -> np.ndarray:
        unit = np.atleast_2d(np.asarray(unit, dtype=float))
        return np.column_stack([p.from_unit(unit[:, i]) for i, p in enumerate(self.parameters)])

    def clip(self, values: np.ndarray) -> np.ndarray:
        """``values`` (…, d) clipped into the bounds: exp∘log may round a bound one ulp past
        itself, and Optuna refuses a trial outside its distribution."""
        return np.clip(values, [p.low for p in self.parameters], [p.high for p in self.parameters])

    def to_dict(self) -> list[dict[str, object]]:
        return [p.to_dict() for p in self.parameters]

    @classmethod
    def from_dict(cls, items: list[dict[str, object]]) -> ParameterSpace:
        return cls(tuple(ParameterSpec(**item) for item in items))  # type: ignore[arg-type]


PAPER_SPACE = ParameterSpace(
    (
        ParameterSpec("ecoat_gpa", 0.5, 4.0, log=True, unit="GPa"),
        ParameterSpec("scoat_gpa", 0.05, 0.4, log=True, unit="GPa"),
        ParameterSpec("tcoat_mm", 0.01, 0.1, log=True, unit="mm"),
    )
)
"""The paper's stage-1 ranges (its Table 1), log-scaled."""
