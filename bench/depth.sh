#!/usr/bin/env bash
# `stagehand process --products depth` against the rig's capture rate (issue 14: 8 cameras at
# 7.5 Hz during sweeps, 60 frames/s of 1024×768, so a scan can be checked while it runs).
# Renders, on the built-in rig drawn as built ([sim.as_built] seed 3), a checkerboard run
# (calibrated first), then sequences/mdf_laser.rhai at one laser position with a sweep of
# LINES lines (default 64, the script's) and of twice that, calibrates the laser planes, and
# times space-time depth, the per-frame baseline and the MDF merge on each: raw frames per
# second, peak memory (VmHWM via /usr/bin/time), and the projected time for a full
# mdf_laser.rhai capture at its defaults (160,368 raw frames).
#
# Usage: bench/depth.sh [WIDTH HEIGHT [LINES]]      (default 1024 768 64)
# Environment: STAGEHAND_BIN (default target/release/stagehand, built if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
width="${1:-1024}"
height="${2:-768}"
lines="${3:-64}"
bin="${STAGEHAND_BIN:-target/release/stagehand}"
[ -x "$bin" ] || cargo build --release
[ -x /usr/bin/time ] || { echo "bench/depth.sh needs /usr/bin/time (apt-get install time)" >&2; exit 2; }

source bench/lib/rig.sh
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
as_built_rig "$width" "$height"

echo "== geometry calibration (${width}×${height})" >&2
checkerboard_geometry
echo "geometry $geometry_id covers $cameras" >&2

printf '%-7s %-20s %9s %8s %9s %10s %12s\n' "lines" "products" "raw frms" "wall s" "raw fps" "peak MiB" "full (min)"
for n in "$lines" $((2 * lines)); do
    out="$work/mdf-$n"
    "$bin" run sequences/mdf_laser.rhai --rig "$work/rig.toml" --out "$out" --yes \
        --set views=1 --set positions=1 --set mounts=1 --set lines="$n" > /dev/null
    run="$(ls -d "$out"/mdf_laser-*)"
    mkdir -p "$out/calibrations"
    cp -r "$work/runs/calibrations/$geometry_id" "$out/calibrations/"
    planes_id="$("$bin" calibrate laser-planes "$run" --geometry "$geometry_id" --json \
        | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')"
    raw="$(python3 -c "import sqlite3,sys; c=sqlite3.connect(sys.argv[1]); cams=sys.argv[2].split(','); q='SELECT count(*) FROM frames WHERE kind=\"raw\" AND laser_on AND fixture != \"planes\" AND camera IN (%s)' % ','.join('?'*len(cams)); print(c.execute(q, cams).fetchone()[0])" "$run/index.sqlite" "$cameras")"
    for case in "depth space-time" "depth per-frame" "mdf space-time"; do
        set -- $case
        clear_products "$run"
        /usr/bin/time -f '%e %M' -o "$work/time" "$bin" process "$run" --products "$1" \
            --depth-method "$2" --calibration "$geometry_id" --calibration "$planes_id" \
            --cameras "$cameras" --json > "$work/summary.json"
        read -r wall kib < "$work/time"
        python3 - "$n" "$1 $2" "$raw" "$wall" "$kib" <<'PY'
import sys
n, what, raw, wall, kib = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
fps = raw / wall
full = 160_368
print(f"{n:7} {what:20} {raw:9d} {wall:8.1f} {fps:9.1f} {kib / 1024:10.0f} {full / fps / 60:12.1f}")
PY
    done
done
