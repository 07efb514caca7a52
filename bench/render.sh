#!/usr/bin/env bash
# Renderer benchmark: frames per second for a full 8-camera step of the built-in light stage
# (1024×768) at each quality preset, 1 and 2 threads, with the memory peak per preset.
#
#   bench/render.sh                       all presets (reference takes a few minutes)
#   bench/render.sh preview               one preset (or a comma list: preview,standard)
#
# Other subsets through the environment: STAGEHAND_RENDER_BENCH_SCENES=lamp|laser,
# STAGEHAND_RENDER_BENCH_THREADS=2, STAGEHAND_RENDER_BENCH_REPS=3. Prints a Markdown table.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -gt 0 ]; then
  export STAGEHAND_RENDER_BENCH="$1"
fi
cargo bench --quiet -p stagehand-simulator --bench render
