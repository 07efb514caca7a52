#!/usr/bin/env bash
# Depth accuracy over the whole sample (issue 14's targets): for each SCENE, renders
# sequences/mdf_laser.rhai on the built-in rig drawn as built ([sim.as_built] seed 3, ground
# truth on) at one view with POSITIONS laser directions (light-arc angles of one mount), each
# sweep of ±SWEEP° in LINES lines (0.025° a line by default: the sheet moves about half its
# width between frames, as space-time analysis needs), covering the sample; stores the
# simulator's exact cameras as the geometry (`calibrate geometry --from-truth`, so the figures
# measure the depth method, not the geometric calibration), calibrates the laser planes from
# the run's fixture frames, makes the MDF (space-time depth merged over the directions) and
# the naive per-frame baseline (each frame's peak per column, as Horus and FabScan do) from
# the same frames, and prints `stagehand evaluate`'s figures side by side: RMSE, 99th
# percentile and median in pixel footprints, the hole fraction, and the laser planes' error.
#
# Usage: bench/depth_accuracy.sh [WIDTH HEIGHT [POSITIONS [LINES [SWEEP [SCENES...]]]]]
#        (default 240 180 4 80 1.0 bumps weave: ±1° covers about a third of the sample; ±3.5°
#        in 280 lines covers it all, at about 30 min a scene)
# Environment: STAGEHAND_BIN (default target/release/stagehand, built if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
width="${1:-240}"
height="${2:-180}"
positions="${3:-4}"
lines="${4:-80}"
sweep="${5:-1.0}"
shift $(( $# < 5 ? $# : 5 ))
if [ $# -gt 0 ]; then scenes=("$@"); else scenes=(bumps weave); fi
bin="${STAGEHAND_BIN:-target/release/stagehand}"
[ -x "$bin" ] || cargo build --release

source bench/lib/rig.sh
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
as_built_rig "$width" "$height"
sed -i 's/^\[sim\]$/[sim]\nground_truth = ["depth"]/' "$work/rig.toml"

echo "${width}×${height}, ${positions} laser directions, ${lines} lines over ±${sweep}° each" >&2
printf '%-8s %-22s %8s %8s %8s %8s %8s\n' "scene" "product" "rmse fp" "p99 mm" "med fp" "known" "holes"
for scene in "${scenes[@]}"; do
    out="$work/$scene"
    "$bin" run sequences/mdf_laser.rhai --rig "$work/rig.toml" --out "$out" --yes \
        --set views=1 --set positions="$positions" --set mounts=1 --set lines="$lines" \
        --set sweep_deg="$sweep" --set sample="$scene" > /dev/null
    run="$(ls -d "$out"/mdf_laser-*)"
    geometry_id="$("$bin" calibrate geometry "$run" --from-truth --json \
        | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')"
    planes_id="$("$bin" calibrate laser-planes "$run" --geometry "$geometry_id" --json \
        | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')"
    "$bin" process "$run" --products mdf --calibration "$geometry_id" \
        --calibration "$planes_id" --json > /dev/null
    "$bin" process "$run" --products depth --depth-method per-frame \
        --calibration "$geometry_id" --calibration "$planes_id" --json > /dev/null
    "$bin" evaluate "$run" > "$work/report.json"
    python3 - "$scene" "$work/report.json" <<'PY'
import json, sys
scene, report = sys.argv[1], json.load(open(sys.argv[2]))
def row(name, f, holes=""):
    print(f"{scene:8} {name:22} {f['rmse_footprints']:8.3f} {f['p99_mm']:8.3f} "
          f"{f['median_footprints']:8.3f} {f.get('known_fraction', float('nan')):8.3f} {holes:>8}")
mdf, sweeps, naive = report["mdf"], report["depth"], report["depth_per_frame"]
row("mdf (space-time)", mdf, f"{mdf['hole_fraction']:.3f}")
row("sweeps (space-time)", sweeps)
row("per-frame baseline", naive)
print(f"{scene:8} baseline / MDF RMSE: {naive['rmse_footprints'] / mdf['rmse_footprints']:.1f}×; "
      f"laser planes within {max(p['max_angle_deg'] for p in report['laser_planes']):.3f}°")
PY
done
