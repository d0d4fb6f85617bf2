#!/usr/bin/env bash
# Set up (scripts/setup.sh, scripts/system-packages.sh) and run the whole test suite.
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
bash scripts/system-packages.sh
exec .venv/bin/python -m pytest -q "$@"
