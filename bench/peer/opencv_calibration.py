#!/usr/bin/env python3
"""Peer for the calibration benchmark: OpenCV's geometric and response calibration on the
same images stagehand calibrates.

Input: a JSON job on stdin (written by `bench/calibration.sh` from a simulated calibration run):
  {"pattern": {"cols": 9, "rows": 6, "square_mm": 20.0},
   "cameras": {"cam1": {"width": 1024, "height": 768, "views": ["/abs/frame.png", ...]}},
   "brackets": {"cam1": {"bit_depth": 12, "exposures": [[0.005, "/abs/frame.png"], ...]}}}

Output: one JSON object on stdout:
  {"opencv": "4.x", "geometry": {"cam1": {"found": 11, "views": 12, "rms_px": ..,
     "fx": .., "fy": .., "cx": .., "cy": .., "dist": [k1, k2, p1, p2, k3], "time_s": ..}},
   "response": {"cam1": {"inverse_response": [[g_b, g_g, g_r] per 8-bit level], "time_s": ..},
   "merge_time_s": ..}

Method (OpenCV's documented pipeline): findChessboardCorners on an 8-bit view of each frame,
cornerSubPix (11×11 window, 30 iterations / 0.001 px), calibrateCamera with k1, k2, p1, p2 (and
k3 when the job says "fit_k3": true, as stagehand's --fit-k3);
createCalibrateDebevec (OpenCV's Debevec–Malik, 8-bit only, so frames are reduced to their top
8 bits) and createMergeDebevec on the same bracket. Times are wall clock of the OpenCV calls only.
"""
import json
import sys
import time

import cv2
import numpy as np


def to_8bit(img16, bit_depth):
    shift = max(bit_depth - 8, 0)
    return (img16 >> shift).clip(0, 255).astype(np.uint8)


def load(path):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img


def geometry(job):
    pattern = job["pattern"]
    size = (pattern["cols"], pattern["rows"])
    obj = np.zeros((size[0] * size[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0:size[0], 0:size[1]].T.reshape(-1, 2) * pattern["square_mm"]
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    out = {}
    for cam, spec in job["cameras"].items():
        images = [load(p) for p in spec["views"]]
        t0 = time.perf_counter()
        objpoints, imgpoints = [], []
        for img in images:
            gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            if gray.dtype != np.uint8:
                gray = (gray.astype(np.float64) * 255.0 / max(int(gray.max()), 1)).astype(np.uint8)
            ok, corners = cv2.findChessboardCorners(gray, size, None)
            if not ok:
                continue
            corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), criteria)
            objpoints.append(obj)
            imgpoints.append(corners)
        entry = {"views": len(images), "found": len(imgpoints)}
        if len(imgpoints) >= 3:
            # Like stagehand's default, k3 stays 0 unless the job asks to fit it.
            flags = 0 if job.get("fit_k3", False) else cv2.CALIB_FIX_K3
            rms, k, dist, _, _ = cv2.calibrateCamera(
                objpoints, imgpoints, (spec["width"], spec["height"]), None, None, flags=flags)
            d = dist.ravel().tolist()
            entry.update({"rms_px": rms, "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2],
                          "cy": k[1, 2], "dist": d})
        entry["time_s"] = time.perf_counter() - t0
        out[cam] = entry
    return out


def response(job):
    out = {}
    merge_time = 0.0
    for cam, spec in job.get("brackets", {}).items():
        times = np.array([t for t, _ in spec["exposures"]], dtype=np.float32)
        images = [to_8bit(load(p), spec["bit_depth"]) for _, p in spec["exposures"]]
        t0 = time.perf_counter()
        curve = cv2.createCalibrateDebevec().process(images, times)
        t1 = time.perf_counter()
        cv2.createMergeDebevec().process(images, times, curve)
        merge_time += time.perf_counter() - t1
        out[cam] = {"inverse_response": curve.reshape(256, 3).tolist(), "time_s": t1 - t0}
    return out, merge_time


def main():
    job = json.load(sys.stdin)
    geo = geometry(job)
    resp, merge_time = response(job)
    json.dump({"opencv": cv2.__version__, "geometry": geo, "response": resp,
               "merge_time_s": merge_time}, sys.stdout)
    print()


if __name__ == "__main__":
    main()
