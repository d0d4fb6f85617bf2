#!/usr/bin/env bash
# Set up (scripts/setup.sh) and run the main job on the embedded defaults.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/surrogate simulate --ecoat 1.0 --scoat 0.2 --tcoat 0.012 "$@"
