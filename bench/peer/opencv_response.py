#!/usr/bin/env python3
"""Peer for the response benchmark: OpenCV's Debevec–Malik camera-response calibration on the
same exposure sweep stagehand calibrates.

Input: a JSON job on stdin (written by `bench/response.sh` from a calibration_response run):
  {"cameras": {"cam1": {"bit_depth": 12, "sample_shift": 4,
                        "exposures": [[0.0005, "/abs/frame.png"], ...]}}}

Output: one JSON object on stdout:
  {"opencv": "4.x", "cameras": {"cam1": {"g": [[g_r, g_g, g_b] per 8-bit level],
     "level_dn": [camera DN each level stands for], "reduced_bits": 4,
     "time_s": .., "merge_time_s": .., "load_time_s": ..}}}
g is ln of OpenCV's curve (CalibrateDebevec returns exp g), in R, G, B order (OpenCV's is B, G, R).

Method (OpenCV's documented pipeline, default parameters: 70 samples on a grid, lambda 10):
the raw PNGs are MSB-aligned, so each frame is shifted right by its `sample_shift` to get the
DN. CalibrateDebevec takes 8-bit images only: an 8-bit camera's DNs go in as they are; a
12-bit camera's are reduced to their top 8 bits (DN >> 4), as any OpenCV user has to, and
level k then stands for DNs 16k … 16k + 15 (`level_dn` is their middle, 16k + 7.5).
MergeDebevec is run on the same bracket with the recovered curve, for its time only.
Times are wall clock of the OpenCV calls only, after the images are loaded.
"""
import json
import sys
import time

import cv2
import numpy as np


def load(path, sample_shift, bit_depth):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    dn = img >> sample_shift
    return (dn >> max(bit_depth - 8, 0)).clip(0, 255).astype(np.uint8)


def main():
    job = json.load(sys.stdin)
    out = {}
    for cam, spec in sorted(job["cameras"].items()):
        bits = spec["bit_depth"]
        reduced = max(bits - 8, 0)
        t0 = time.perf_counter()
        times = np.array([t for t, _ in spec["exposures"]], dtype=np.float32)
        images = [load(p, spec["sample_shift"], bits) for _, p in spec["exposures"]]
        t1 = time.perf_counter()
        curve = cv2.createCalibrateDebevec().process(images, times)
        t2 = time.perf_counter()
        cv2.createMergeDebevec().process(images, times, curve)
        t3 = time.perf_counter()
        bgr = curve.reshape(256, 3).astype(np.float64)
        step = 1 << reduced
        out[cam] = {
            "g": np.log(bgr[:, ::-1]).tolist(),
            "level_dn": [k * step + (step - 1) / 2 for k in range(256)],
            "reduced_bits": reduced,
            "time_s": t2 - t1,
            "merge_time_s": t3 - t2,
            "load_time_s": t1 - t0,
        }
    json.dump({"opencv": cv2.__version__, "cameras": out}, sys.stdout)
    print()


if __name__ == "__main__":
    main()
