# Shared by scripts/demo.sh and scripts/test.sh: create .venv at the repository root (if
# missing), install mocap-calib into it and compile its numerical kernels into their cache (so
# that no later run compiles them). $1: pip extras ("" or "[test]").
# pip's output goes to .venv/install.log and is shown only if the install fails.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-python3}"
if [ ! -x "$ROOT/.venv/bin/python" ]; then
  "$PY" -m venv "$ROOT/.venv"
fi
LOG="$ROOT/.venv/install.log"
if ! { "$ROOT/.venv/bin/python" -m pip install --quiet --upgrade pip \
       && "$ROOT/.venv/bin/python" -m pip install --quiet -e "$ROOT$1" \
       && "$ROOT/.venv/bin/python" -m compileall -q "$ROOT/mocap_calib"; } >"$LOG" 2>&1; then
  cat "$LOG" >&2
  echo "error: installing mocap-calib failed (log above, also in $LOG)" >&2
  exit 1
fi
echo "compiling mocap-calib's numerical kernels (once after installing) ..."
if ! OUT="$("$ROOT/.venv/bin/mocap-calib" compile 2>&1)"; then
  echo "$OUT" >&2
  echo "error: compiling mocap-calib's kernels failed (output above)" >&2
  exit 1
fi
echo "$OUT"
