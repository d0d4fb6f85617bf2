"""Gaussian-process surrogates (scikit-learn): pure numerics, arrays in, records out.

- :class:`CoatingSurrogate` — F60, θsat and the force curve over a study's
  parameter space (the main job's surrogate; ``surrogate fit``/``predict``), on the
  physical coating features of :class:`FeatureMap`.
- :class:`CurveSurrogate` — the whole force curve over parameters × test conditions
  (the calibration's), on whatever inputs the caller's feature function gives.
- :class:`Discrepancy` — what an expensive solver adds to the built-in one, learned
  from a few expensive runs (the multi-fidelity correction; numpy and SciPy only).

The two curve surrogates reduce curves to one :class:`~surrogate.gp._basis.PrincipalBasis`.
Nothing here reads files of a study, prints, or sees an Optuna object.
"""

from .._lazy import lazy_attributes

# scikit-learn loads with the first surrogate used: the discrepancy and the curve scale
# (numpy and SciPy only) serve the solvers without it.
_LAZY = {
    "CurveSurrogate": "._curves",
    "FeatureMap": "._features",
    "CoatingSurrogate": "._model",
    "cross_validation_table": "._model",
    "Discrepancy": "._discrepancy",
    "FORCE_SCALE_N": "._scale",
    "force_of_latent": "._scale",
    "latent_of_force": "._scale",
    "latent_slope": "._scale",
}

__all__ = [
    "FORCE_SCALE_N",
    "CoatingSurrogate",
    "CurveSurrogate",
    "Discrepancy",
    "FeatureMap",
    "cross_validation_table",
    "force_of_latent",
    "latent_of_force",
    "latent_slope",
]

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
