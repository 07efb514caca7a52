#!/usr/bin/env bash
# `stagehand process` on a scaled version of seed 004's local reflectance capture (Table 5.6:
# 12×7 views × 12×7 lights, 3-exposure HDR brackets of 1024×768, rectified to 256²; the seed
# took about 4 hours on a 3.2 GHz Xeon). Renders, on the built-in rig drawn as built
# ([sim.as_built] seed 3), a checkerboard run and a response sweep (calibrated first), then
# sequences/btf.rhai at two sizes (2 table angles × 1 and × 2 light-arc angles × 7 lamps, all
# 8 cameras), and times `process --products btf` and `--products rectified,btf` on each:
# raw frames per second, peak memory (VmHWM via /usr/bin/time), and the projected time for
# the full capture (12·7 · 12·7 captures × 3 exposures = 21,168 raw frames).
#
# Usage: bench/process.sh [WIDTH HEIGHT]      (default 1024 768, the rig's cameras)
# Environment: STAGEHAND_BIN (default target/release/stagehand, built if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
width="${1:-1024}"
height="${2:-768}"
bin="${STAGEHAND_BIN:-target/release/stagehand}"
[ -x "$bin" ] || cargo build --release
[ -x /usr/bin/time ] || { echo "bench/process.sh needs /usr/bin/time (apt-get install time)" >&2; exit 2; }

source bench/lib/rig.sh
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
as_built_rig "$width" "$height"

echo "== calibrations (${width}×${height})" >&2
checkerboard_geometry
"$bin" run sequences/calibration_response.rhai --rig "$work/rig.toml" --out "$work/runs" --yes > /dev/null
response_id="$("$bin" calibrate response "$work"/runs/calibration_response-* --json \
    | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')"
echo "geometry $geometry_id covers $cameras; response $response_id" >&2

printf '%-10s %-16s %9s %8s %9s %10s %12s\n' "capture" "products" "raw frms" "wall s" "raw fps" "peak MiB" "full (min)"
for lights in 1 2; do
    out="$work/btf-$lights"
    "$bin" run sequences/btf.rhai --rig "$work/rig.toml" --out "$out" --yes \
        --set views=2 --set lights=$lights --set lamps=7 > /dev/null
    run="$(ls -d "$out"/btf-*)"
    mkdir -p "$out/calibrations"
    cp -r "$work/runs/calibrations/$geometry_id" "$work/runs/calibrations/$response_id" "$out/calibrations/"
    for products in btf rectified,btf; do
        clear_products "$run"
        /usr/bin/time -f '%e %M' -o "$work/time" "$bin" process "$run" --products "$products" \
            --calibration "$response_id" --calibration "$geometry_id" --cameras "$cameras" --json > "$work/summary.json"
        read -r wall kib < "$work/time"
        raw="$(python3 -c "import sqlite3,sys; c=sqlite3.connect(sys.argv[1]); cams=sys.argv[2].split(','); q='SELECT count(*) FROM frames WHERE kind=\"raw\" AND camera IN (%s)' % ','.join('?'*len(cams)); print(c.execute(q, cams).fetchone()[0])" "$run/index.sqlite" "$cameras")"
        python3 - "$lights" "$products" "$raw" "$wall" "$kib" <<'PY'
import sys
lights, products, raw, wall, kib = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
fps = raw / wall
full = 12 * 7 * 12 * 7 * 3
print(f"2x{lights}x7    {products:16} {raw:9d} {wall:8.1f} {fps:9.1f} {kib / 1024:10.0f} {full / fps / 60:12.1f}")
PY
    done
done
