#!/usr/bin/env bash
# The dashboard's end-to-end test in headless Debian Chromium (playwright-core from npm):
# installs Chromium if missing, the npm dependency from the lock file, then runs e2e.mjs, which
# starts its own daemon from $STAGEHAND_BIN (default target/debug/stagehand, built if missing).
# Screenshots: $SCREENSHOT_DIR (default target/e2e-screenshots). E2E_INSTALL_ONLY=1 stops after
# the installs (CI makes them while it builds).
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"

if [ ! -x /usr/bin/chromium ] && [ -z "${CHROMIUM:-}" ]; then
  echo "e2e: /usr/bin/chromium is missing; installing Debian's chromium" >&2
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { echo "e2e: not root and no sudo: install chromium (apt-get install -y chromium)" >&2; exit 1; }
    SUDO="sudo"
  fi
  $SUDO apt-get update
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y chromium
fi

command -v node >/dev/null || { echo "e2e: node is missing (Node.js 18 or newer)" >&2; exit 1; }
(
  cd "$HERE"
  if [ -f package-lock.json ]; then
    npm ci --no-audit --no-fund --loglevel=error
  else
    npm install --no-audit --no-fund --loglevel=error
  fi
)
[ "${E2E_INSTALL_ONLY:-0}" = 1 ] && exit 0

if [ -z "${STAGEHAND_BIN:-}" ]; then
  export STAGEHAND_BIN="$ROOT/target/debug/stagehand"
  if [ ! -x "$STAGEHAND_BIN" ]; then
    (cd "$ROOT" && cargo build --bin stagehand)
  fi
fi

cd "$ROOT"
exec node "$HERE/e2e.mjs"
