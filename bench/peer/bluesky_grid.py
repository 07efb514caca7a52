#!/usr/bin/env python3
"""Peer benchmark: Bluesky RunEngine per-point overhead with instant simulated devices.

Usage: bluesky_grid.py [N] [REPEATS]
  N        number of points (default 10000); the grid scan uses a x b = N with
           a the largest divisor of N not above sqrt(N) (100 x 100 for 10000)
  REPEATS  timed runs per plan, best reported (default 1; env BLUESKY_BENCH_REPEATS).
           The default is 1, not 3, because one 10000-point run already takes about a
           minute or more here (several ms per point); each plan gets one untimed
           10-point warm-up run first so that the single timed run is not a cold one.

Devices: ophyd.sim motor1 / motor2 (SynAxis, delay=0) and a SynSignal detector
whose value function returns a constant and whose exposure_time is 0, so trigger
and read do no work: what is timed is the RunEngine's own per-point cost
(messages, status objects, document generation). No callbacks are subscribed and
RE.md is empty, so documents are emitted to nobody.

Besides the wall-clock figures (the ones to compare) the JSON carries the process
CPU time of the best run and the 1-minute load average, because on a shared
machine wall time also counts time spent waiting for a core.

stdout: exactly one JSON line. stderr: python / package versions and per-run times.
"""
import json
import math
import os
import platform
import sys
import time

import bluesky
import bluesky.plans as bp
import ophyd
from bluesky import RunEngine
from ophyd.sim import SynSignal, motor1, motor2


def grid_shape(n):
    a = int(math.isqrt(n))
    while a > 1 and n % a:
        a -= 1
    return a, n // a


def best_of(RE, make_plan, repeats, label):
    """Best wall time (perf_counter around RE(plan)) over `repeats` runs, plus the
    process CPU time (all threads) of that same run."""
    runs = []
    for i in range(repeats):
        plan = make_plan()
        c0 = time.process_time()
        t0 = time.perf_counter()
        RE(plan)
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
        runs.append((wall, cpu))
        print(f"{label} run {i + 1}/{repeats}: wall {wall:.3f} s, cpu {cpu:.3f} s", file=sys.stderr)
    return min(runs)


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10000
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else int(os.environ.get("BLUESKY_BENCH_REPEATS", "1"))
    if n < 1 or repeats < 1:
        sys.exit("N and REPEATS must be >= 1")

    # Cheapest possible detector: constant value, no exposure delay, no noise.
    det = SynSignal(name="det", func=lambda: 1.0, exposure_time=0)
    for m in (motor1, motor2):
        m.delay = 0  # instant moves (already the default in ophyd.sim)

    # context_managers=[]: no SIGINT handler installed, so this also works outside
    # the main thread / without a terminal. md={} keeps metadata minimal.
    RE = RunEngine({}, context_managers=[])

    # Untimed warm-up of both plan types (first-run caches, lazy imports).
    RE(bp.grid_scan([det], motor1, 0.0, 1.0, 2, motor2, 0.0, 1.0, 5, snake_axes=False))
    RE(bp.scan([det], motor1, 0.0, 1.0, 10))

    a, b = grid_shape(n)
    grid_best, grid_cpu = best_of(
        RE,
        lambda: bp.grid_scan([det], motor1, 0.0, 1.0, a, motor2, 0.0, 1.0, b, snake_axes=False),
        repeats,
        f"grid_scan {a}x{b}",
    )
    scan_best, scan_cpu = best_of(RE, lambda: bp.scan([det], motor1, 0.0, 1.0, n), repeats, f"scan {n}")

    try:
        load1 = round(os.getloadavg()[0], 2)  # context: the machine may be shared
    except OSError:
        load1 = None
    pyver = platform.python_version()
    print(f"python {pyver} ({platform.python_implementation()}), bluesky {bluesky.__version__}, "
          f"ophyd {ophyd.__version__}", file=sys.stderr)
    print(json.dumps({
        "peer": "bluesky",
        "bluesky": bluesky.__version__,
        "ophyd": ophyd.__version__,
        "python": pyver,
        "points": n,
        "grid_shape": [a, b],
        "repeats": repeats,
        "grid_best_s": round(grid_best, 6),
        "grid_us_per_point": round(grid_best / n * 1e6, 3),
        "grid_cpu_s": round(grid_cpu, 6),
        "scan_best_s": round(scan_best, 6),
        "scan_us_per_point": round(scan_best / n * 1e6, 3),
        "scan_cpu_s": round(scan_cpu, 6),
        "loadavg_1m": load1,
    }))


if __name__ == "__main__":
    main()
