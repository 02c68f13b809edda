#!/usr/bin/env bash
# Render an HTML report (or any local page) to a PNG with headless Chromium.
#   scripts/render_report.sh report.html out.png [WIDTH [HEIGHT]]
# WIDTH x HEIGHT is the browser window in CSS pixels (default 1280 x 3200; the picture is the
# top HEIGHT pixels of the page). Needs Debian's chromium (apt-get install -y chromium).
# No network: the reports are self-contained, and Chromium's background connections are off.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 report.html out.png [WIDTH [HEIGHT]]" >&2
  exit 2
fi
IN="$1"
OUT="$2"
WIDTH="${3:-1280}"
HEIGHT="${4:-3200}"
if [ ! -f "$IN" ]; then
  echo "error: $IN: no such file" >&2
  exit 2
fi
CHROME="${CHROMIUM:-$(command -v chromium || command -v chromium-browser || true)}"
if [ -z "$CHROME" ]; then
  echo "error: chromium not found; install it (Debian: apt-get install -y chromium) or set CHROMIUM" >&2
  exit 2
fi
PROFILE="$(mktemp -d)"
trap 'rm -rf "$PROFILE"' EXIT
ABS_IN="$(cd "$(dirname "$IN")" && pwd)/$(basename "$IN")"
mkdir -p "$(dirname "$OUT")"
ABS_OUT="$(cd "$(dirname "$OUT")" && pwd)/$(basename "$OUT")"
rm -f "$ABS_OUT"
SANDBOX=()
if [ "$(id -u)" = "0" ]; then
  SANDBOX=(--no-sandbox)  # Chromium refuses to run as root with its sandbox
fi
"$CHROME" --headless "${SANDBOX[@]}" --disable-gpu --disable-quic --no-first-run \
  --disable-background-networking --disable-component-update --disable-sync \
  --hide-scrollbars --user-data-dir="$PROFILE" --window-size="$WIDTH,$HEIGHT" \
  --screenshot="$ABS_OUT" "file://$ABS_IN" >"$PROFILE/chromium.log" 2>&1 || {
  cat "$PROFILE/chromium.log" >&2
  echo "error: chromium failed to render $IN" >&2
  exit 1
}
if [ ! -s "$ABS_OUT" ]; then
  cat "$PROFILE/chromium.log" >&2
  echo "error: chromium wrote no picture for $IN" >&2
  exit 1
fi
echo "wrote $OUT"
