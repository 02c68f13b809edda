# Shared by scripts/demo.sh and scripts/test.sh: create .venv at the repository root (if
# missing) and install mocap-calib into it. $1: pip extras ("" or "[test]").
# pip's output goes to .venv/install.log and is shown only if the install fails.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3}"
if [ ! -x "$ROOT/.venv/bin/python" ]; then
  "$PY" -m venv "$ROOT/.venv"
fi
LOG="$ROOT/.venv/install.log"
if ! { "$ROOT/.venv/bin/python" -m pip install --quiet --upgrade pip \
       && "$ROOT/.venv/bin/python" -m pip install --quiet -e "$ROOT$1"; } >"$LOG" 2>&1; then
  cat "$LOG" >&2
  echo "error: installing mocap-calib failed (log above, also in $LOG)" >&2
  exit 1
fi
