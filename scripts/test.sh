#!/usr/bin/env bash
# The test command: set up (venv, package, GL libraries) and run the test suite on real GL (EGL).
#   bash scripts/test.sh            default suite (slow tests deselected)
#   bash scripts/test.sh --all      everything, slow tests included
#   bash scripts/test.sh -k engine  extra arguments go to pytest
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/setup.sh"
cd "$ROOT"
"$PY" -m gltrack info
MARK=(-m "not slow")
if [ "${1:-}" = "--all" ]; then MARK=(); shift; fi
exec "$PY" -m pytest -q "${MARK[@]}" "$@"
