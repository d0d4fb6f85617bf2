"""The schema of a study: what every command reads, validated once.

- ``_spec``: study files (``studies/*.toml``) → a frozen ``StudySpec``;
- ``_space``: the declared coating parameters (``ParameterSpec``,
  ``ParameterSpace``, ``PAPER_SPACE``, ``COATING_PARAMETERS``);
- ``_rig``: the test rig (``Rig``); ``_conditions``: a test's conditions and
  the rig they make;
- ``_measurements``: measured curves (``MeasurementSet``, ``load_measurements``);
  ``_formats`` and ``_lab_files``: files as labs export them (``MeasurementFormat``,
  the ``[measurements]`` keys);
- ``_samples``: solver runs of a design (``SampleSet``);
- ``_units``: GPa at the interfaces, MPa inside; measured forces and angles into N
  and degrees.

The study file's ``[solver]`` section is checked against the solver registry
(:mod:`surrogate.solvers`), which itself reads rigs and spaces from here; so
``StudySpec`` and ``load_study`` are not re-exported (that would make this
package and ``solvers`` import each other): import them from
``surrogate.study._spec`` or the top-level ``surrogate``. The pandas-backed
names (``SampleSet``, ``MeasurementSet`` …) load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ._conditions import CONDITIONS, DIRECTIONS, check_conditions, rig_for
from ._formats import MeasurementFormat
from ._rig import Rig
from ._space import COATING_PARAMETERS, DESIGNS, PAPER_SPACE, ParameterSpace, ParameterSpec
from ._units import MPA_PER_GPA, gpa_to_mpa, mpa_to_gpa

if TYPE_CHECKING:
    from ._measurements import MeasurementSet, load_measurements
    from ._samples import SampleSet, read_points

__all__ = [
    "COATING_PARAMETERS",
    "CONDITIONS",
    "DESIGNS",
    "DIRECTIONS",
    "MPA_PER_GPA",
    "PAPER_SPACE",
    "MeasurementFormat",
    "MeasurementSet",
    "ParameterSpace",
    "ParameterSpec",
    "Rig",
    "SampleSet",
    "check_conditions",
    "gpa_to_mpa",
    "load_measurements",
    "mpa_to_gpa",
    "read_points",
    "rig_for",
]


def __getattr__(name: str) -> Any:
    """The pandas-backed names, imported on first use (``import surrogate`` stays light)."""
    if name in ("SampleSet", "read_points"):
        from . import _samples

        return getattr(_samples, name)
    if name in ("MeasurementSet", "load_measurements"):
        from . import _measurements

        return getattr(_measurements, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
