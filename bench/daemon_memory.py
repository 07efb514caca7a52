#!/usr/bin/env python3
"""Peak memory of the daemon during a full-size run.

    bench/daemon_memory.py [--script quickstart] [--runs 1] [--bin target/release/stagehand]

Starts `stagehand serve` on the built-in light stage (full-size 1024x768 cameras, simulated) with
a fresh data directory on a free loopback port, starts the script over the API, confirms its
prompts, waits for each run to end, and samples the daemon's resident memory (/proc/PID/status) every 100 ms. Prints
the RSS before the run, the peak during it (the kernel's VmHWM high-water mark, so no sample
can miss it), the RSS after, the runs' frames, wall time and device faults (from /api/metrics: on the
simulated rig there should be none); the last line is the same as JSON. Build the binary first (`cargo build --release`).
"""
import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request


def status_kib(pid, field):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"no {field} in /proc/{pid}/status")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--script", default="quickstart")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--bin", default="target/release/stagehand")
    ap.add_argument("--rig", default="lightstage")
    args = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    os.chdir(root)
    if not os.access(args.bin, os.X_OK):
        sys.exit(f"{args.bin} is missing: build it first (cargo build --release)")
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    url = f"http://127.0.0.1:{port}"
    work = tempfile.mkdtemp(prefix="stagehand-mem-")
    log = open(os.path.join(work, "daemon.log"), "w")
    daemon = subprocess.Popen(
        [args.bin, "serve", "--rig", args.rig, "--data", f"{work}/data",
         "--listen", f"127.0.0.1:{port}", "--scripts", "sequences"],
        stdout=log, stderr=subprocess.STDOUT)
    try:
        token = None
        for _ in range(600):
            try:
                token = json.load(open(f"{work}/data/tokens.json"))["operator"]
                urllib.request.urlopen(url + "/", timeout=1)
                break
            except Exception:
                time.sleep(0.1)
        if token is None:
            sys.exit(f"the daemon did not start; see {work}/daemon.log")

        def call(method, path, body=None):
            data = None if body is None else json.dumps(body).encode()
            req = urllib.request.Request(url + path, data=data, method=method)
            req.add_header("Authorization", f"Bearer {token}")
            if data is not None:
                req.add_header("Content-Type", "application/json")
            with urllib.request.urlopen(req, timeout=60) as r:
                return json.loads(r.read() or b"null")

        samples = []
        stop = threading.Event()

        def sample():
            while not stop.is_set():
                try:
                    samples.append(status_kib(daemon.pid, "VmRSS"))
                except Exception:
                    return
                time.sleep(0.1)

        before = status_kib(daemon.pid, "VmRSS")
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        t0 = time.monotonic()
        frames = 0
        statuses = []
        for _ in range(args.runs):
            started = call("POST", "/api/runs", {"script": args.script})
            run_id = started["run_id"]
            while True:
                time.sleep(0.5)
                live = call("GET", "/api/status").get("run") or {}
                if live.get("prompt"):
                    # The operator confirms every prompt (as `run --yes` does).
                    call("POST", f"/api/runs/{run_id}/prompt", {"answer": "continue"})
                run = call("GET", f"/api/runs/{run_id}")
                if run.get("status") not in ("running", None) and call("GET", "/api/status").get("run") is None:
                    break
            statuses.append(run.get("status"))
            frames += int(run.get("frames", run.get("frames_written", 0)) or 0)
        wall = time.monotonic() - t0
        peak = status_kib(daemon.pid, "VmHWM")
        req = urllib.request.Request(url + "/api/metrics")
        req.add_header("Authorization", f"Bearer {token}")
        metrics = urllib.request.urlopen(req, timeout=60).read().decode()
        faults = sum(float(line.split()[-1]) for line in metrics.splitlines()
                     if line.startswith("stagehand_device_errors_total"))
        after = status_kib(daemon.pid, "VmRSS")
        stop.set()
        sampler.join()
        mib = lambda kib: kib / 1024.0
        print(f"runs: {args.runs} x {args.script} on {args.rig}: {statuses}, {frames} frames, "
              f"{wall:.1f} s wall, {faults:.0f} device faults")
        print(f"daemon RSS before {mib(before):.0f} MiB, peak {mib(peak):.0f} MiB, after {mib(after):.0f} MiB "
              f"(median sample during the runs {mib(sorted(samples)[len(samples) // 2]) if samples else 0:.0f} MiB)")
        print(json.dumps({"script": args.script, "runs": args.runs, "statuses": statuses,
                          "frames": frames, "wall_s": round(wall, 1), "device_faults": faults,
                          "rss_before_mib": round(mib(before)), "rss_peak_mib": round(mib(peak)),
                          "rss_after_mib": round(mib(after))}))
    finally:
        daemon.terminate()
        try:
            daemon.wait(timeout=20)
        except subprocess.TimeoutExpired:
            daemon.kill()


if __name__ == "__main__":
    main()
