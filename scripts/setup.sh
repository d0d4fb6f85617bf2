#!/usr/bin/env bash
# Create .venv/ with the project (editable), its test tools and the manual's (mkdocs: the
# suite builds the manual, tests/docs).
# Idempotent: a second run only checks that everything is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $("$PYTHON" --version)"
    "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[dev,docs]"
# The built-in solver's kernels and the GP likelihood are compiled by numba on their first
# call and cached beside the source (surrogate/physics/__pycache__, surrogate/gp/__pycache__):
# compile them here, once, rather than in the first processes of the first run (the suite's
# pytest processes each compiled them: 27 s of CPU a compile on the loaded 2-core AMD EPYC).
# A second setup finds them cached.
echo "setup: compiling the built-in solver's and the GP's kernels (numba; cached after the first time)"
.venv/bin/python -c "
import numpy as np, surrogate
from surrogate.gp._curves import _kernel
from surrogate.gp._regressor import Regressor
surrogate.simulate(1.0, 0.2, 0.012)  # a plain curve; then hardening, self-weight, a clamp spring
surrogate.simulate(1.0, 0.2, 0.012, effects={'hardening': {'ratio': 0.1},
    'gravity': {'areal_mass_g_m2': 500.0}, 'clamp_slip': {'k_nmm_rad': 200.0}})
X = np.linspace(0.0, 1.0, 12).reshape(6, 2)
Regressor(kernel=_kernel(2), normalize_y=True).fit(X, X.sum(axis=1))  # the likelihood"
echo "setup: ready (.venv/bin/surrogate)"
