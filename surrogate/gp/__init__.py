"""Gaussian-process surrogates (scikit-learn): pure maths, arrays in and out."""

from ._features import FeatureMap
from ._model import CoatingSurrogate, cross_validation_table

__all__ = ["CoatingSurrogate", "FeatureMap", "cross_validation_table"]
