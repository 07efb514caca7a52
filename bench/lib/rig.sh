# Shared set-up of the bench scripts that process captures (sourced, not run): the built-in rig
# drawn as built, and its checkerboard geometry calibration.

# Writes $work/rig.toml (devices/rigs/lightstage.toml at WIDTH×HEIGHT, drawn as built with
# [sim.as_built] seed 3 and the "gentle" response, then EXTRA appended) and $work/rig-aa.toml
# (the same with 2×2 antialiasing, for the checkerboard). Needs $work.
as_built_rig() {
    local width="$1" height="$2" extra="${3:-}"
    sed -e "s/width = 1024/width = $width/; s/height = 768/height = $height/" \
        devices/rigs/lightstage.toml > "$work/rig.toml"
    printf '\n[sim.as_built]\nseed = 3\nresponse = "gentle"\n%s' "$extra" >> "$work/rig.toml"
    cp "$work/rig.toml" "$work/rig-aa.toml"
    printf '\n[sim.knobs]\nspp_side = 2\n' >> "$work/rig-aa.toml"
}

# Runs sequences/calibration_checkerboard.rhai on $work/rig-aa.toml into $work/runs and
# calibrates it: sets geometry_id and cameras (the comma-separated cameras it placed). Needs
# $bin and $work.
checkerboard_geometry() {
    "$bin" run sequences/calibration_checkerboard.rhai --rig "$work/rig-aa.toml" --out "$work/runs" --yes > /dev/null
    local geometry
    geometry="$("$bin" calibrate geometry "$work"/runs/calibration_checkerboard-* --json \
        | python3 -c 'import json,sys; d=json.load(sys.stdin); print(d["id"]); print(",".join(c["camera"] for c in d["result"]["cameras"]))' || true)"
    geometry_id="$(echo "$geometry" | sed -n 1p)"
    cameras="$(echo "$geometry" | sed -n 2p)"
}

# Empties the products of run $1 (files and index), so a timed pass starts from nothing.
clear_products() {
    rm -rf "$1/products"
    python3 -c "import sqlite3,sys; c=sqlite3.connect(sys.argv[1]); c.execute('DELETE FROM products'); c.commit()" "$1/index.sqlite"
}
