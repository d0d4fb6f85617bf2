"""The parameter space's unit-cube mapping."""

import numpy as np

from surrogate._space import ParameterSpec


def test_from_unit_never_leaves_the_bounds():
    # exp(log(0.01) + 1·(log(0.1) − log(0.01))) is 0.10000000000000002 in floating point;
    # Optuna warns of (and a strict consumer rejects) a value past the bound
    spec = ParameterSpec("tcoat_mm", 0.01, 0.1, log=True)
    values = spec.from_unit(np.array([0.0, 1.0]))
    assert values[0] == 0.01 and values[1] == 0.1
    inside = spec.from_unit(np.linspace(0, 1, 1001))
    assert np.all((inside >= 0.01) & (inside <= 0.1))
    assert np.allclose(spec.to_unit(spec.from_unit(np.linspace(0, 1, 11))), np.linspace(0, 1, 11))
