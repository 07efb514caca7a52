#!/usr/bin/env bash
# Camera-response calibration (Debevec–Malik) side by side with OpenCV on the same frames:
# renders sequences/calibration_response.rhai (12 exposures of the colour checker) on the
# built-in rig drawn as built ([sim.as_built] seed 3), in two variants as the integration
# tests do (tests/integration/common/calibration.rs):
#   gentle   scientific 12-bit cameras, y = x(1 − c + c·x)
#   strong   8-bit consumer cameras,    y = x^(1/γ)
# then, for each,
#   stagehand calibrate response + stagehand evaluate   (errors against the simulator's truth)
#   OpenCV createCalibrateDebevec (+ createMergeDebevec)  (bench/peer/opencv_response.py)
# and prints, per camera, each tool's worst-channel error of the recovered inverse response
# against the truth in as_built.json, and each tool's time.
#
# The error is the one `stagehand evaluate` reports (src/evaluate/response.rs): the relative
# error of exp g after the free scale is removed (median log ratio), at 400 DNs over the range
# stagehand's evaluation uses for that camera and channel (observed, trusted, resolved to 1 %).
# OpenCV's curve is measured over the same range in the same way, here in Python. OpenCV only
# takes 8-bit images: the 12-bit frames are reduced to their top 8 bits (DN >> 4), and each of
# its 256 levels is compared at the middle of the 16 DNs it stands for.
#
# Usage: bench/response.sh [WIDTH HEIGHT]      (default 480 360, as the integration tests)
# Environment: STAGEHAND_BIN (default target/release/stagehand, built if missing),
#              STAGEHAND_BENCH_VENV (the peers' venv, see bench/peer/run.sh).
# Times: stagehand's includes reading the run (SQLite, PNG decoding) and storing the result;
# OpenCV's counts CalibrateDebevec's calls only, after the images are loaded (MergeDebevec and
# the loading are shown apart).
set -euo pipefail
cd "$(dirname "$0")/.."
width="${1:-480}"
height="${2:-360}"
bin="${STAGEHAND_BIN:-target/release/stagehand}"
[ -x "$bin" ] || cargo build --release
bench/peer/run.sh --install >&2
py="${STAGEHAND_BENCH_VENV:-target/bench-venv}/bin/python"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
for variant in "gentle 12" "strong 8"; do
  read -r style bits <<< "$variant"
  dir="$work/$style"
  mkdir -p "$dir"
  sed -e "s/width = 1024/width = $width/; s/height = 768/height = $height/" \
      -e "s/bit_depth = 12/bit_depth = $bits/" devices/rigs/lightstage.toml > "$dir/rig.toml"
  printf '\n[sim.as_built]\nseed = 3\nresponse = "%s"\n' "$style" >> "$dir/rig.toml"
  echo "== rendering the exposure sweep (${width}×${height}, $style, $bits-bit)" >&2
  "$bin" run sequences/calibration_response.rhai --rig "$dir/rig.toml" --out "$dir/runs" --yes >&2
  run="$(ls -d "$dir"/runs/calibration_response-*)"

  echo "== stagehand calibrate response" >&2
  t0=$(date +%s.%N)
  "$bin" calibrate response "$run" --json > "$dir/stagehand.json" || true
  t1=$(date +%s.%N)
  "$bin" evaluate "$run" > "$dir/evaluate.json"

  echo "== OpenCV" >&2
  python3 - "$run" > "$dir/job.json" <<'PY'
import json, sqlite3, sys
run = sys.argv[1]
db = sqlite3.connect(f"file:{run}/index.sqlite?mode=ro", uri=True)
cams = {}
for cam, path, t, bits, shift in db.execute(
        "SELECT camera, path, exposure_s, bit_depth, sample_shift FROM frames"
        " WHERE kind = 'raw' ORDER BY camera, exposure_index"):
    c = cams.setdefault(cam, {"bit_depth": bits, "sample_shift": shift, "exposures": []})
    c["exposures"].append([t, f"{run}/{path}"])
print(json.dumps({"cameras": cams}))
PY
  "$py" bench/peer/opencv_response.py < "$dir/job.json" > "$dir/opencv.json"

  python3 - "$run" "$dir" "$t0" "$t1" "$style" "$bits" <<'PY'
import bisect, json, math, struct, sys
run, dir, t0, t1, style, bits = sys.argv[1:]
stagehand_time = float(t1) - float(t0)
truth = json.load(open(f"{run}/as_built.json"))["cameras"]
ev = json.load(open(f"{dir}/evaluate.json"))["response"]
ours = ev[0]["cameras"] if ev else {}
cv = json.load(open(f"{dir}/opencv.json"))
f32 = lambda v: struct.unpack("f", struct.pack("f", v))[0]  # the truth is f32 in the simulator

def ln_x(cam, c, z):
    """ln of the true fraction of the full well giving DN z (simulator's Response::invert)."""
    t = truth[cam]
    full = (1 << t["bit_depth"]) - 1
    y = min(max((z - math.floor(0.02 * full + 0.5)) / full, 0.0), 1.0)  # black level 2 %
    r = t["response"]
    if r["kind"] == "gamma":
        return f32(r["gamma"][c]) * math.log(y)
    k = f32(r["curvature"][c])
    return math.log(y if abs(k) < 1e-12 else (math.sqrt((1 - k) ** 2 + 4 * k * y) - (1 - k)) / (2 * k))

def interp(xs, ys, z):  # as InverseResponse::g: linear between knots, clamped
    k = min(max(bisect.bisect_right(xs, z), 1), len(xs) - 1) - 1
    a = min(max((z - xs[k]) / (xs[k + 1] - xs[k]), 0.0), 1.0)
    return (1 - a) * ys[k] + a * ys[k + 1]

def errors(cam, c, xs, ys, lo, hi):  # as evaluate_response: 400 DNs, median log offset
    logs = [ln_x(cam, c, z) - interp(xs, ys, z) for z in (lo + (hi - lo) * i / 399 for i in range(400))]
    off = sorted(logs)[len(logs) // 2]
    e = [abs(math.exp(l - off) - 1) for l in logs]
    return max(e), math.sqrt(sum(v * v for v in e) / len(e))

# Check the Python measure against evaluate's on stagehand's own curves.
fits = json.load(open(f"{dir}/stagehand.json")).get("result", {}) if ours else {}
for cam, chans in ours.items():
    for c, (fig, g) in enumerate(zip(chans, fits[cam]["channels"])):
        mine = errors(cam, c, g["knots_dn"], g["g"], *fig["dn_range"])
        assert abs(mine[0] - fig["max_rel_error"]) < 1e-6, (cam, c, mine, fig)

reduced = {v["reduced_bits"] for v in cv["cameras"].values()}
note = f"reduced to 8 bits (DN >> {max(reduced)})" if max(reduced) else "DNs as they are"
print(f"\n== {style} responses, {bits}-bit cameras; OpenCV {cv['opencv']}: {note}")
print(f"{'camera':6} | {'stagehand max %':>15} {'rms %':>7} | {'OpenCV max %':>12} {'rms %':>7} | DN range (worst channel)")
cv_time = merge_time = load_time = 0.0
for cam in sorted(truth):
    o, k = ours.get(cam), cv["cameras"].get(cam)
    cv_time += k["time_s"]; merge_time += k["merge_time_s"]; load_time += k["load_time_s"]
    if not o:
        print(f"{cam:6} | {'left out':>15} {'':7} | {'(no DN range)':>12}")
        continue
    cvf = [errors(cam, c, k["level_dn"], [g[c] for g in k["g"]], *o[c]["dn_range"]) for c in range(3)]
    w = max(range(3), key=lambda c: o[c]["max_rel_error"])
    lo, hi = o[w]["dn_range"]
    print(f"{cam:6} | {100 * max(f['max_rel_error'] for f in o):15.3f} {100 * max(f['rms_rel_error'] for f in o):7.3f} | "
          f"{100 * max(e[0] for e in cvf):12.3f} {100 * max(e[1] for e in cvf):7.3f} | {lo:.0f}–{hi:.0f}")
print(f"time: stagehand {stagehand_time:.2f} s (whole command), OpenCV {cv_time:.2f} s (CalibrateDebevec), "
      f"ratio {stagehand_time / max(cv_time, 1e-9):.1f} ({stagehand_time / max(cv_time + load_time, 1e-9):.1f} counting "
      f"OpenCV's image loading, {load_time:.2f} s); OpenCV MergeDebevec {merge_time:.2f} s")
PY
done
