#!/usr/bin/env bash
# Executor benchmarks with the Bluesky peer measured in the same run.
#
#   bench/run.sh [STEPS]        (default 10000; the Bluesky side takes ~5 minutes at 10000)
#
# Prints the JSON lines of both sides, then a summary with the ratio
# (Bluesky µs per point ÷ stagehand µs per step). Set STAGEHAND_SKIP_PEER=1 to skip Bluesky.
set -euo pipefail
cd "$(dirname "$0")/.."
steps="${1:-10000}"
results="$(mktemp)"
trap 'rm -f "$results"' EXIT

echo "== stagehand executor ($steps steps)" >&2
STAGEHAND_BENCH_STEPS="$steps" cargo bench --quiet --bench executor_overhead | tee -a "$results"

if [ "${STAGEHAND_SKIP_PEER:-0}" != "1" ]; then
  echo "== Bluesky RunEngine + ophyd.sim ($steps points)" >&2
  if ! bench/peer/run.sh "$steps" | tee -a "$results"; then
    echo "the Bluesky peer could not be run; see above" >&2
  fi
fi

python3 - "$results" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
by = {r.get("bench", r.get("peer")): r for r in rows}
nf, fr, btf, bs = (by.get(k) for k in ("executor_no_frames", "executor_frames_flowing", "btf_estimate", "bluesky"))
print("\nsummary")
if nf:
    print(f"  stagehand executor, no frames     {nf['us_per_step']:10.1f} µs/step  (target ≤ 20)")
if fr:
    print(f"  stagehand executor, frames        {fr['us_per_step']:10.1f} µs/step  ({fr['frames']} frames {fr['camera']})")
if btf:
    print(f"  btf.rhai estimate vs simulated    {btf['relative_error']*100:+10.2f} %        (target within ±5 %)")
if bs and nf:
    print(f"  Bluesky grid_scan (ophyd.sim)     {bs['grid_us_per_point']:10.1f} µs/point  → {bs['grid_us_per_point']/nf['us_per_step']:.0f}× stagehand")
    print(f"  Bluesky scan (ophyd.sim)          {bs['scan_us_per_point']:10.1f} µs/point  → {bs['scan_us_per_point']/nf['us_per_step']:.0f}× stagehand")
PY
