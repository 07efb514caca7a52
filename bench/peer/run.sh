#!/usr/bin/env bash
# Peer benchmark: Bluesky RunEngine per-point overhead (see bluesky_grid.py).
#
# Usage: bench/peer/run.sh [N] [REPEATS]        (defaults: 10000, 1)
#        bench/peer/run.sh --install           (only create/update the venv: it also holds
#                                               Mitsuba 3 for `stagehand sim tradeoff --mitsuba`)
#
# Creates or reuses a Python venv at ${STAGEHAND_BENCH_VENV:-target/bench-venv}
# (a relative path is taken from the repo root), installs requirements.txt into it
# quietly (skipped when that exact requirements.txt was already installed there),
# then prints the peer's JSON line on stdout. Progress and versions go to stderr.
#
# Environment:
#   STAGEHAND_BENCH_VENV   venv location (default target/bench-venv)
#   PYTHON                 interpreter for creating the venv (default python3.11,
#                          else python3)
#
# Exit status: 0 ok; 2 bad usage; 3 the peer could not be installed (no network,
# pip or venv failure); otherwise the benchmark's own status.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo_root="$(cd "$here/../.." && pwd)"
cd "$repo_root"

install_only=0
if [ "${1:-}" = "--install" ]; then install_only=1; shift; fi

n="${1:-10000}"
repeats="${2:-${BLUESKY_BENCH_REPEATS:-1}}"
case "$n$repeats" in
  *[!0-9]*|"") echo "usage: $0 [N] [REPEATS]  (positive integers)" >&2; exit 2 ;;
esac

venv="${STAGEHAND_BENCH_VENV:-target/bench-venv}"
req="$here/requirements.txt"

fail_install() {
  echo "bench/peer: the Bluesky peer could not be installed: $1" >&2
  echo "bench/peer: (PyPI must be reachable to install $req into $venv)" >&2
  exit 3
}

if [ -z "${PYTHON:-}" ]; then
  if command -v python3.11 >/dev/null 2>&1; then PYTHON=python3.11; else PYTHON=python3; fi
fi

if [ ! -x "$venv/bin/python" ]; then
  echo "bench/peer: creating venv $venv with $PYTHON" >&2
  "$PYTHON" -m venv "$venv" >&2 || fail_install "could not create venv with $PYTHON"
fi
py="$venv/bin/python"

# Reinstall only when requirements.txt changed since the last successful install.
stamp="$venv/.stagehand-peer-requirements"
if ! cmp -s "$req" "$stamp" 2>/dev/null; then
  echo "bench/peer: installing $(basename "$req") into $venv" >&2
  if ! "$py" -m pip install --quiet --disable-pip-version-check \
       --retries 2 --timeout 30 -r "$req" >&2; then
    fail_install "pip install -r bench/peer/requirements.txt failed"
  fi
  cp "$req" "$stamp"
fi

if [ "$install_only" = 1 ]; then
  echo "bench/peer: venv ready: $py" >&2
  exit 0
fi

exec "$py" "$here/bluesky_grid.py" "$n" "$repeats"
