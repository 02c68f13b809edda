# Shared by scripts/demo.sh and scripts/test.sh: create .venv at the repository root (if
# missing) and install mocap-calib into it. $1: pip extras ("" or "[test]").
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3}"
if [ ! -x "$ROOT/.venv/bin/python" ]; then
  "$PY" -m venv "$ROOT/.venv"
fi
"$ROOT/.venv/bin/python" -m pip install --quiet --upgrade pip >/dev/null
"$ROOT/.venv/bin/python" -m pip install --quiet -e "$ROOT$1"
