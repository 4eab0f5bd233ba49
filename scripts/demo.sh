#!/usr/bin/env bash
# The demo command: set up (venv, package, GL libraries) and run `gltrack demo`.
#   bash scripts/demo.sh [--out DIR]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/setup.sh"
exec "$PY" -m gltrack demo "$@"
