#!/usr/bin/env bash
# The aravis camera backend against eight fake GigE Vision cameras (arv-fake-gv-camera-0.8 on
# 127.0.0.2-9, GVCP and GVSP over loopback): discovery, opening by address/serial/id, software
# trigger, exposure and gain read back, exact trigger accounting at the rig's rate, a camera
# killed and restarted, and 1 % lost packets (devices/tests/aravis_gige.rs); with
# STAGEHAND_GIGE_QUICKSTART=1, also the whole quickstart on the eight cameras.
#
# Needs root (apt-get, a network namespace, loopback addresses). Any test that cannot start the
# cameras fails (STAGEHAND_REQUIRE_PEERS=1) instead of skipping. Extra arguments go to the test
# binary, e.g.
#   .ci/gige.sh --ignored --nocapture measure_eight_cameras     # the figures
# A first argument `install`, `build` or `test` runs only that part (CI overlaps them with other
# work); without one, all three run.
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=never

sudo_=""
[ "$(id -u)" = 0 ] || sudo_="sudo"

part="all"
case "${1:-}" in
    install|build|test) part="$1"; shift ;;
esac

packages="aravis-tools libaravis-dev libgphoto2-dev libusb-1.0-0-dev libclang-dev pkg-config"
missing=""
for p in $packages; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ] && [ "$part" != test ]; then
    echo "== installing$missing"
    $sudo_ apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_ apt-get install -y -qq $missing >/dev/null
fi
[ "$part" = install ] && exit 0

# The whole quickstart on the cameras needs the binary built with every camera backend (about
# 3.5 minutes of CI with its run): opt in with STAGEHAND_GIGE_QUICKSTART=1.
quickstart="${STAGEHAND_GIGE_QUICKSTART:-0}"
if [ "$part" != test ]; then
    echo "== cargo test --no-run, cargo build (outside the namespace: they may need crates.io)"
    cargo test -p stagehand-devices --features cam-v4l,cam-aravis,cam-gphoto2 --test aravis_gige --no-run
    if [ "$quickstart" = 1 ]; then
        cargo build -p stagehand --features cam-v4l,cam-aravis,cam-gphoto2
    fi
fi
[ "$part" = build ] && exit 0

# aravis's discovery broadcasts on every interface that is up, so the cameras and the tests run
# in a private network namespace with only loopback: nothing leaves the machine.
echo "== in a private network namespace: lo up, 127.0.0.2-9, cargo test -p stagehand-devices --features cam-aravis --test aravis_gige"
$sudo_ unshare --net -- env STAGEHAND_REQUIRE_PEERS=1 bash -euo pipefail -c '
    ip link set lo up
    for n in 2 3 4 5 6 7 8 9; do
        ip -4 -o addr show dev lo | grep -q "inet 127.0.0.$n/" || ip addr add "127.0.0.$n/8" dev lo
    done
    cargo test --offline -p stagehand-devices --features cam-v4l,cam-aravis,cam-gphoto2 --test aravis_gige -- "$@"
' gige "$@"

# The whole quickstart with the 8 GigE cameras real (through aravis) and the serial devices
# (GRBL, relay board) on their emulators: every step done, every frame from a fake camera
# (512×512, the fake's size; the simulated cameras would be 1024×768).
if [ "$quickstart" != 1 ]; then
    echo "== the quickstart on 8 GigE cameras: skipped (STAGEHAND_GIGE_QUICKSTART=1 runs it)"
    exit 0
fi
echo "== in a private network namespace: the quickstart on 8 GigE cameras and emulated serial devices"
$sudo_ unshare --net -- bash -euo pipefail -c '
    ip link set lo up
    pids=""
    for n in 2 3 4 5 6 7 8 9; do
        ip -4 -o addr show dev lo | grep -q "inet 127.0.0.$n/" || ip addr add "127.0.0.$n/8" dev lo
        arv-fake-gv-camera-0.8 -i "127.0.0.$n" -s "GV0$n" >/dev/null 2>&1 &
        pids="$pids $!"
    done
    trap "kill $pids 2>/dev/null" EXIT
    sleep 2
    out="$(mktemp -d)"
    "${CARGO_TARGET_DIR:-target}/debug/stagehand" run --rig devices/rigs/lightstage-gige.toml \
        --emulate sequences/quickstart.rhai --yes --out "$out"
    db="$(ls -d "$out"/*/index.sqlite)"
    python3 - "$db" <<PY
import sqlite3, sys
rows = sqlite3.connect(sys.argv[1]).execute(
    "SELECT count(*), min(width), max(width), min(height), max(height) FROM frames WHERE kind = '"'"'raw'"'"'").fetchone()
assert rows == (72, 512, 512, 512, 512), rows
print("quickstart on 8 GigE cameras: 72 raw frames, all 512x512 from the fake cameras")
PY
'
