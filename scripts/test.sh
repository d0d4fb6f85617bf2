#!/usr/bin/env bash
# Set up (scripts/setup.sh, scripts/system-packages.sh) and run the whole test suite, one pytest
# process a core and one more for the tests that mostly wait (pytest-xdist; tests/conftest.py
# groups those). Extra arguments go to pytest (-n 0: one process).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
bash scripts/system-packages.sh   # PostgreSQL, Chromium and CalculiX for the system tests (root: installs)
exec .venv/bin/python -m pytest -q -n auto --dist loadgroup "$@"   # pytest-xdist: see tests/conftest.py
