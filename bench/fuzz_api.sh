#!/usr/bin/env bash
# Fuzzes the daemon's HTTP API from its own OpenAPI document with schemathesis (PyPI).
#
#   bench/fuzz_api.sh [MAX_EXAMPLES]     (default 30 per operation; a few minutes)
#
# Installs schemathesis 4.x into a venv (target/fuzz-venv, or $STAGEHAND_FUZZ_VENV), builds
# and starts `stagehand serve` on the small simulated light stage with a fresh data directory
# on a free loopback port, and runs `schemathesis run http://127.0.0.1:PORT/openapi.json` with
# the operator token. The live event stream (/api/events) and the WebSocket (/api/ws/jog) are
# left out: they never end by design. Checks: no 5xx (`not_a_server_error`), plus response
# schema, status code and content type conformance with the document.
#
# Exit status: non-zero if any request got a 5xx (or the daemon died); conformance failures
# are reported and fail the script only with STAGEHAND_FUZZ_STRICT=1. The full report (JUnit
# and NDJSON) goes to target/fuzz-report/, the daemon's log to target/fuzz-report/daemon.log.
set -euo pipefail
cd "$(dirname "$0")/.."
examples="${1:-30}"
venv="$(realpath -m "${STAGEHAND_FUZZ_VENV:-target/fuzz-venv}")"
report_dir="$(realpath -m target/fuzz-report)"
strict="${STAGEHAND_FUZZ_STRICT:-0}"

if [ ! -x "$venv/bin/schemathesis" ]; then
  echo "== installing schemathesis into $venv" >&2
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --upgrade pip
  "$venv/bin/pip" install --quiet 'schemathesis>=4,<5'
fi
echo "== $("$venv/bin/schemathesis" --version)" >&2

# CI passes the binary its tests just built (STAGEHAND_FUZZ_NO_BUILD=1): `cargo build` after
# `cargo test` would compile the crate again without the dev-dependencies' features.
if [ "${STAGEHAND_FUZZ_NO_BUILD:-0}" != 1 ]; then
  echo "== building stagehand" >&2
  cargo build --quiet --bin stagehand
fi

work="$(mktemp -d)"
daemon_pid=""
cleanup() {
  if [ -n "$daemon_pid" ] && kill -0 "$daemon_pid" 2>/dev/null; then
    kill -TERM "$daemon_pid" 2>/dev/null || true
    wait "$daemon_pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT

# The small simulated light stage: cameras 64×48 so fuzzed captures render quickly.
sed -e 's/^width = 1024/width = 64/' -e 's/^height = 768/height = 48/' \
  devices/rigs/lightstage.toml > "$work/rig.toml"
port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
url="http://127.0.0.1:$port"
mkdir -p "$report_dir"
rm -f "$report_dir"/*.xml "$report_dir"/*.ndjson

echo "== starting the daemon on $url (data in $work/data)" >&2
"${CARGO_TARGET_DIR:-target}/debug/stagehand" serve --rig "$work/rig.toml" --data "$work/data" \
  --listen "127.0.0.1:$port" --scripts sequences > "$report_dir/daemon.log" 2>&1 &
daemon_pid=$!
for _ in $(seq 1 100); do
  if [ -f "$work/data/tokens.json" ] && python3 - "$url" <<'PY' 2>/dev/null; then break; fi
import sys, urllib.request
urllib.request.urlopen(sys.argv[1] + "/openapi.json", timeout=1).read()
PY
  if ! kill -0 "$daemon_pid" 2>/dev/null; then
    echo "the daemon exited; its log:" >&2
    cat "$report_dir/daemon.log" >&2
    exit 1
  fi
  sleep 0.2
done
token="$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["operator"])' "$work/data/tokens.json")"

echo "== schemathesis: $examples examples per operation" >&2
set +e
# From the scratch directory: schemathesis keeps a cache (.schemathesis/) in its working directory.
(cd "$work" && "$venv/bin/schemathesis" run "$url/openapi.json" \
  --header "Authorization: Bearer $token" \
  --checks not_a_server_error,response_schema_conformance,status_code_conformance,content_type_conformance \
  --exclude-path /api/events \
  --exclude-path /api/ws/jog \
  --max-examples "$examples" \
  --workers 1 \
  --seed 1 \
  --request-timeout 60 \
  --suppress-health-check all \
  --report junit,ndjson \
  --report-dir "$report_dir" \
  --output-truncate false)
fuzz_status=$?
set -e

alive=1
kill -0 "$daemon_pid" 2>/dev/null || alive=0

# 5xx from the recorded interactions (NDJSON), other failures from the JUnit report.
python3 - "$report_dir" "$alive" "$strict" "$fuzz_status" <<'PY'
import base64, collections, glob, json, re, sys
import xml.etree.ElementTree as ET
report_dir, alive, strict, fuzz_status = sys.argv[1], sys.argv[2] == "1", sys.argv[3] == "1", int(sys.argv[4])

def interactions(o):
    if isinstance(o, dict):
        if isinstance(o.get("response"), dict) and isinstance(o.get("request"), dict):
            yield o
        for v in o.values():
            yield from interactions(v)
    elif isinstance(o, list):
        for v in o:
            yield from interactions(v)

def text(content):
    if isinstance(content, dict) and "$base64" in content:
        return base64.b64decode(content["$base64"]).decode("utf-8", "replace")
    return str(content or "")

statuses = collections.Counter()
server = []
for path in glob.glob(f"{report_dir}/*.ndjson"):
    for line in open(path):
        for it in interactions(json.loads(line)):
            code = it["response"].get("status_code")
            if not isinstance(code, int):
                continue
            statuses[code] += 1
            if code >= 500:
                req = it["request"]
                server.append(f"{req.get('method')} {req.get('uri')} body={text(req.get('body'))[:300]!r} "
                              f"→ {code} {text(it['response'].get('content'))[:300]}")

checks = collections.defaultdict(set)
for path in glob.glob(f"{report_dir}/*.xml"):
    for case in ET.parse(path).getroot().iter("testcase"):
        for failure in list(case.iter("failure")) + list(case.iter("error")):
            body = (failure.text or "") + (failure.get("message") or "")
            for title in re.findall(r"^- (.+)$", body, re.M) or ["error: " + body.strip()[:200]]:
                checks[title.strip()].add(case.get("name"))

print()
print("fuzz summary")
print("  responses by status: " + ", ".join(f"{k}: {v}" for k, v in sorted(statuses.items())))
print(f"  server errors (5xx): {len(server)}")
for s in server:
    print(f"    {s}")
for title, ops in sorted(checks.items()):
    print(f"  {title}: {len(ops)} operations")
    for op in sorted(ops):
        print(f"    {op}")
if not alive:
    print("  the daemon died during the fuzzing; see target/fuzz-report/daemon.log")
bad = bool(server) or not alive or (strict and (checks or fuzz_status != 0))
print("  result: " + ("FAIL" if bad else "ok (no 5xx)"))
sys.exit(1 if bad else 0)
PY
