#!/usr/bin/env bash
# Geometric calibration side by side with OpenCV on the same frames (issue 13's peer):
# renders sequences/calibration_checkerboard.rhai on the built-in rig drawn as built
# ([sim.as_built] seed 3, 2×2 antialiasing), then
#   stagehand calibrate geometry + stagehand evaluate      (errors against the simulator's truth)
#   OpenCV findChessboardCorners + cornerSubPix + calibrateCamera (bench/peer/opencv_calibration.py)
# and prints, per camera, each tool's reprojection RMS, focal-length and principal-point errors
# against the truth in as_built.json, and each tool's time.
#
# Usage: bench/calibration.sh [WIDTH HEIGHT]      (default 1024 768, the rig's cameras)
# Environment: STAGEHAND_BIN (default target/release/stagehand, built if missing),
#              STAGEHAND_BENCH_VENV (the peers' venv, see bench/peer/run.sh).
# Times: stagehand's includes reading the run (SQLite, PNG decoding) and storing the result;
# OpenCV's counts its calls only, after the images are loaded.
set -euo pipefail
cd "$(dirname "$0")/.."
width="${1:-1024}"
height="${2:-768}"
bin="${STAGEHAND_BIN:-target/release/stagehand}"
[ -x "$bin" ] || cargo build --release
bench/peer/run.sh --install >&2
py="${STAGEHAND_BENCH_VENV:-target/bench-venv}/bin/python"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
sed -e "s/width = 1024/width = $width/; s/height = 768/height = $height/" \
    devices/rigs/lightstage.toml > "$work/rig.toml"
printf '\n[sim.as_built]\nseed = 3\nresponse = "gentle"\n\n[sim.knobs]\nspp_side = 2\n' >> "$work/rig.toml"
echo "== rendering the checkerboard placements (${width}×${height})" >&2
"$bin" run sequences/calibration_checkerboard.rhai --rig "$work/rig.toml" --out "$work/runs" --yes >&2
run="$(ls -d "$work"/runs/calibration_checkerboard-*)"

echo "== stagehand calibrate geometry" >&2
t0=$(date +%s.%N)
"$bin" calibrate geometry "$run" --json > "$work/stagehand.json" || true
t1=$(date +%s.%N)
"$bin" evaluate "$run" > "$work/evaluate.json"

echo "== OpenCV" >&2
python3 - "$run" > "$work/job.json" <<'PY'
import json, sqlite3, sys
run = sys.argv[1]
db = sqlite3.connect(f"{run}/index.sqlite")
cams = {}
for cam, path, w, h in db.execute(
        "SELECT camera, path, width, height FROM frames WHERE fixture = 'checkerboard' AND kind = 'raw' ORDER BY step"):
    c = cams.setdefault(cam, {"width": w, "height": h, "views": []})
    c["views"].append(f"{run}/{path}")
print(json.dumps({"pattern": {"cols": 8, "rows": 7, "square_mm": 8.0}, "cameras": cams}))
PY
"$py" bench/peer/opencv_calibration.py < "$work/job.json" > "$work/opencv.json"

python3 - "$run" "$work" "$t0" "$t1" <<'PY'
import json, math, sys
run, work, t0, t1 = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
truth = json.load(open(f"{run}/as_built.json"))["cameras"]
ev = json.load(open(f"{work}/evaluate.json"))["geometry"][0]
cv = json.load(open(f"{work}/opencv.json"))
ours = {c["camera"]: c for c in ev["cameras"]}
print(f"{'camera':6} | {'stagehand rms px':>16} {'f err %':>8} {'pp err px':>9} | {'OpenCV views':>12} {'rms px':>7} {'f err %':>8} {'pp err px':>9}")
cv_time = 0.0
for cam in sorted(truth):
    t = truth[cam]["geometry"]
    o = ours.get(cam)
    s = (f"{o['rms_px']:16.3f} {100*o['focal_rel_error']:8.3f} {o['principal_point_error_px']:9.2f}"
         if o else f"{'left out':>16} {'':8} {'':9}")
    c = cv["geometry"].get(cam, {})
    cv_time += c.get("time_s", 0.0)
    if "fx" in c:
        fe = max(abs(c["fx"] / t["fx"] - 1), abs(c["fy"] / t["fy"] - 1))
        pe = math.hypot(c["cx"] - t["cx"], c["cy"] - t["cy"])
        k = f"{c['found']:>5}/{c['views']:<6} {c['rms_px']:7.3f} {100*fe:8.3f} {pe:9.2f}"
    else:
        k = f"{c.get('found', 0):>5}/{c.get('views', 0):<6} {'too few views':>26}"
    print(f"{cam:6} | {s} | {k}")
print(f"time: stagehand {t1 - t0:.2f} s (whole command), OpenCV {cv_time:.2f} s (its calls), "
      f"ratio {(t1 - t0) / max(cv_time, 1e-9):.2f}; stagehand left out {len(ev['failed'])} camera(s), "
      f"board not found in {ev['not_detected']} frame(s); OpenCV {cv['opencv']}")
PY
