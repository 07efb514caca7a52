#!/usr/bin/env bash
# The aravis camera backend against eight fake GigE Vision cameras (arv-fake-gv-camera-0.8 on
# 127.0.0.2-9, GVCP and GVSP over loopback): discovery, opening by address/serial/id, software
# trigger, exposure and gain read back, exact trigger accounting at the rig's rate, a camera
# killed and restarted, and 1 % lost packets (devices/tests/aravis_gige.rs).
#
# Needs root (apt-get, a network namespace, loopback addresses). Any test that cannot start the
# cameras fails (STAGEHAND_REQUIRE_PEERS=1) instead of skipping. Extra arguments go to the test
# binary, e.g.
#   .ci/gige.sh --ignored --nocapture measure_eight_cameras     # the figures
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TERM_COLOR=never

sudo_=""
[ "$(id -u)" = 0 ] || sudo_="sudo"

packages="aravis-tools libaravis-dev libusb-1.0-0-dev libclang-dev pkg-config"
missing=""
for p in $packages; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
    echo "== installing$missing"
    $sudo_ apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_ apt-get install -y -qq $missing >/dev/null
fi

echo "== cargo test --no-run (build outside the namespace: it may need crates.io)"
cargo test -p stagehand-devices --features cam-aravis --test aravis_gige --no-run

# aravis's discovery broadcasts on every interface that is up, so the cameras and the tests run
# in a private network namespace with only loopback: nothing leaves the machine.
echo "== in a private network namespace: lo up, 127.0.0.2-9, cargo test -p stagehand-devices --features cam-aravis --test aravis_gige"
$sudo_ unshare --net -- env STAGEHAND_REQUIRE_PEERS=1 bash -euo pipefail -c '
    ip link set lo up
    for n in 2 3 4 5 6 7 8 9; do
        ip -4 -o addr show dev lo | grep -q "inet 127.0.0.$n/" || ip addr add "127.0.0.$n/8" dev lo
    done
    cargo test --offline -p stagehand-devices --features cam-aravis --test aravis_gige -- "$@"
' gige "$@"
