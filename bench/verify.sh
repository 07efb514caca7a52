#!/usr/bin/env bash
# `stagehand verify` on a 10,000-frame run (1,250 captures × 8 cameras of 64×48 on the simulated
# light stage): the library call three times with a one-thread SHA-256 baseline measured on the
# same files (bench/verify.rs), then the release CLI itself three times on that run.
#
#   bench/verify.sh            (STAGEHAND_VERIFY_FRAMES / STAGEHAND_VERIFY_SIZE as in the bench)
set -euo pipefail
cd "$(dirname "$0")/.."
keep="$(mktemp -d "${TMPDIR:-/tmp}/stagehand-verify.XXXXXX")"
trap 'rm -rf "$keep"' EXIT

STAGEHAND_VERIFY_KEEP="$keep" cargo bench --quiet --bench verify | tee "$keep/result.json"
cargo build --release --quiet
run_dir="$(python3 -c 'import json, sys; print(json.loads(open(sys.argv[1]).read().splitlines()[-1])["run_dir"])' "$keep/result.json")"
for i in 1 2 3; do
  start=$(date +%s.%N)
  target/release/stagehand verify "$run_dir" > "$keep/report.txt"
  end=$(date +%s.%N)
  echo "stagehand verify (CLI, run $i): $(python3 -c "print(f'{$end - $start:.2f}')") s; $(head -1 "$keep/report.txt")"
done
start=$(date +%s.%N)
(cd "$run_dir" && find frames -type f -print0 | xargs -0 sha256sum > /dev/null)
end=$(date +%s.%N)
echo "sha256sum over the same files: $(python3 -c "print(f'{$end - $start:.2f}')") s"
