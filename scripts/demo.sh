#!/usr/bin/env bash
# Install mocap-calib into .venv, simulate a 90 s drone session with known truth, calibrate it,
# print the estimates next to the truth and write a rerun recording of the result.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/_venv.sh" ""
OUT="${1:-$ROOT/out/demo}"
MC="$ROOT/.venv/bin/mocap-calib"
rm -rf "$OUT"
"$MC" simulate "$OUT/session" --seed 7 --effect time_offset=0.012
"$MC" calibrate "$OUT/session" --out "$OUT/calib.yaml" --rrd "$OUT/calib.rrd"
"$ROOT/.venv/bin/python" "$ROOT/scripts/compare_truth.py" "$OUT/calib.yaml" "$OUT/session/truth.yaml"
echo
echo "Open the recording with: $MC view $OUT/calib.rrd"
