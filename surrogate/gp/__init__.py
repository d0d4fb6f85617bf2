"""Gaussian-process surrogates (scikit-learn): pure numerics, arrays in, records out.

- :class:`CoatingSurrogate` — F60, θsat and the force curve over a study's
  parameter space (the main job's surrogate; ``surrogate fit``/``predict``), on the
  physical coating features of :class:`FeatureMap`.
- :class:`CurveSurrogate` — the whole force curve over parameters × test conditions
  (the calibration's), on whatever inputs the caller's feature function gives.

Both reduce curves to one :class:`~surrogate.gp._basis.PrincipalBasis`. Nothing here
reads files of a study, prints, or sees an Optuna object.
"""

from ._curves import CurveSurrogate
from ._features import FeatureMap
from ._model import CoatingSurrogate, cross_validation_table

__all__ = ["CoatingSurrogate", "CurveSurrogate", "FeatureMap", "cross_validation_table"]
