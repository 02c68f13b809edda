#!/usr/bin/env bash
# Install mocap-calib with its test extras into .venv and run the test suite.
# Tests run on every core (pytest-xdist); extra arguments go to pytest
# (e.g. scripts/test.sh -k calibrate -x, or -n 0 for one process).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/_venv.sh" "[test]"
cd "$ROOT"
"$ROOT/.venv/bin/ruff" check mocap_calib tests scripts
"$ROOT/.venv/bin/python" -m pytest -q -n auto "$@"
