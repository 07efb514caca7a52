#!/usr/bin/env python3
"""Peer for `stagehand sim tradeoff --mitsuba`: renders the scene stagehand exported with
Mitsuba 3 (variant scalar_rgb, path tracer) at a sweep of samples per pixel, timing each
render and measuring its error against Mitsuba's own high-spp converged image.

Usage: mitsuba_render.py SCENE_JSON OUT_JSON [--spp 1,2,4,...] [--reference-spp N]
                         [--repeat N] [--sampler NAME]     (sampler default: multijitter)
                         [--glossy sum|roughplastic]

A GGX sample renders as stagehand's model (Lambert + GGX lobe with the dielectric's Fresnel,
summed: a `blendbsdf` of `diffuse` and `roughconductor`, each doubled) unless --glossy
roughplastic asks for Mitsuba's rough plastic (diffuse base under a Fresnel coating).

A `sheet` emitter (stagehand's line laser) becomes Mitsuba's `projector`, its texture baked
against the loaded geometry so the projector's irradiance where each texel's ray lands is the
sheet's (see sheet_projector).

SCENE_JSON is the `scene.json` stagehand's exporter wrote (meshes, albedo texture, a GGX lobe
rendered as `roughplastic`, emitters and camera in the renderer's sample frame, millimetres; see
tradeoff/src/mitsuba.rs). Writes OUT_JSON (times, errors, versions) and the
converged image as `mitsuba_reference.pfm` beside it, which stagehand compares with its own
converged reference to check that both renderers see the same scene.

Timing: the scene load (PLY meshes, texture, BVH build) is measured once and reported as
load_s; each spp count is rendered REPEAT times (best wall-clock time kept, seed varied; once
when a render takes over 2 s), the
first render at each count is also the one whose error is reported. Errors are over every
channel value: RMSE, max abs, and RMSE over the converged image's mean.

stdout: one summary line. stderr: versions and per-render times.
"""
import argparse
import json
import os
import sys
import time

import numpy as np

import mitsuba as mi


def load_scene(desc, base):
    cam = desc["camera"]
    sensor = {
        "type": "perspective",
        "fov": float(cam["fov_deg"]),
        "fov_axis": cam.get("fov_axis", "x"),
        "near_clip": 1.0,
        "far_clip": 1.0e5,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=cam["origin"], target=cam["target"], up=cam["up"]
        ),
        "film": {
            "type": "hdrfilm",
            "width": int(cam["width"]),
            "height": int(cam["height"]),
            "pixel_format": "rgb",
            "component_format": "float32",
            # The renderer averages its sub-pixel samples uniformly over the pixel.
            "rfilter": {"type": "box"},
        },
        "sampler": {"type": desc.get("sampler", "independent")},
    }
    sample = desc["sample"]
    turntable = desc["turntable"]
    albedo = {
        "type": "bitmap",
        "filename": os.path.join(base, sample["albedo"]),
        "filter_type": "nearest",
        "wrap_mode": "clamp",
        "raw": True,
    }
    ggx = sample.get("ggx")
    if ggx and desc.get("glossy", "sum") == "roughplastic":
        # Mitsuba's rough plastic: the same GGX alpha over the dielectric of that F0, its
        # diffuse base under the coating (Fresnel-weighted, with internal reflections).
        sample_bsdf = {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": float(ggx["alpha"]),
            "int_ior": float(ggx["eta"]),
            "ext_ior": 1.0,
            "diffuse_reflectance": albedo,
            "nonlinear": False,
        }
    elif ggx:
        # stagehand's model term for term: Lambert plus a GGX microfacet lobe with the
        # Fresnel of the dielectric of that F0, summed. Mitsuba blends (1 - w) A + w B, so
        # each part is doubled under w = 1/2.
        doubled = dict(albedo)
        doubled["filename"] = os.path.join(base, sample["albedo_doubled"])
        sample_bsdf = {
            "type": "blendbsdf",
            "weight": 0.5,
            "diffuse": {"type": "diffuse", "reflectance": doubled},
            "lobe": {
                "type": "roughconductor",
                "distribution": "ggx",
                "alpha": float(ggx["alpha"]),
                "eta": float(ggx["eta"]),
                "k": 0.0,
                "specular_reflectance": 2.0,
            },
        }
    else:
        sample_bsdf = {"type": "diffuse", "reflectance": albedo}
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(desc["max_depth"])},
        "sensor": sensor,
        "sample": {
            "type": "ply",
            "filename": os.path.join(base, sample["mesh"]),
            "bsdf": sample_bsdf,
        },
        "turntable": {
            "type": "ply",
            "filename": os.path.join(base, turntable["mesh"]),
            "bsdf": {
                "type": "diffuse",
                "reflectance": {"type": "rgb", "value": [float(turntable["albedo"])] * 3},
            },
        },
    }
    for k, e in enumerate(desc["emitters"]):
        if e["type"] == "sphere":
            scene[f"lamp{k}"] = {
                "type": "sphere",
                "center": e["centre"],
                "radius": float(e["radius_mm"]),
                "emitter": {
                    "type": "area",
                    "radiance": {"type": "rgb", "value": e["radiance_rgb"]},
                },
            }
        elif e["type"] == "point":
            scene[f"lamp{k}"] = {
                "type": "point",
                "position": e["position"],
                "intensity": {"type": "rgb", "value": e["intensity_rgb"]},
            }
        elif e["type"] == "sheet":
            # Placed after the geometry is loaded: its texture is baked against the scene.
            continue
        else:
            raise SystemExit(f"unknown emitter type {e['type']!r}")
    sheets = [(k, e) for k, e in enumerate(desc["emitters"]) if e["type"] == "sheet"]
    if sheets:
        geometry = mi.load_dict(scene)
        for k, e in sheets:
            scene[f"laser{k}"] = sheet_projector(e, geometry)
    return mi.load_dict(scene)


def sheet_irradiance(e, p):
    """The laser sheet's irradiance at points p (N×3) on a surface square to the ray, as
    stagehand's `LaserSheet::irradiance` defines the physical sheet: a Gaussian profile of
    1/e² half-width `half_width_mm` across the plane, falling as 1/r along it (a fan of
    constant thickness), zero beyond the fan's half-angle."""
    o = np.array(e["origin"])
    n = np.array(e["normal"])
    c = np.array(e["centre"])
    v = p - o
    d = v @ n
    r = np.linalg.norm(v, axis=1)
    in_plane = v - np.outer(d, n)
    sigma2 = 0.25 * e["half_width_mm"] ** 2
    inside = (in_plane @ c) > np.cos(np.radians(e["fan_half_angle_deg"])) * np.linalg.norm(
        in_plane, axis=1)
    near = d * d <= 36.0 * sigma2
    gauss = np.exp(-0.5 * d * d / sigma2)
    return np.where(inside & near & (r > 1e-3),
                    e["peak"] * gauss * e["ref_distance_mm"] / np.maximum(r, 1e-3), 0.0)


def sheet_projector(e, geometry):
    """The laser sheet as Mitsuba's `projector`: a pinhole at the fan's apex looking along
    its central ray, texture x along the fan and y across the sheet. Each texel's direction is
    taken from a perspective sensor of the same parameters (the projector's own mapping), cast
    into the scene, and the texel set so the projector's irradiance at that first hit,
    pi * T / (z^2 cos theta), equals the sheet's: exact wherever the sheet lands."""
    o = np.array(e["origin"])
    c = np.array(e["centre"])
    n = np.array(e["normal"])
    sigma = 0.5 * e["half_width_mm"]
    r_near, r_far = e["range_mm"]
    texel = sigma / 3.0 / r_far  # tangent-plane texel: a third of sigma at the far end
    half_x = np.tan(np.radians(e["cover_half_angle_deg"]))
    half_y = 7.0 * sigma / r_near
    w = int(np.ceil(2 * half_x / texel))
    h = int(np.ceil(2 * half_y / texel)) | 1
    fov = float(np.degrees(2 * np.arctan(half_x)))
    to_world = mi.ScalarTransform4f().look_at(
        origin=o.tolist(), target=(o + c).tolist(), up=n.tolist())
    sensor = mi.load_dict({
        "type": "perspective", "fov": fov, "fov_axis": "x", "to_world": to_world,
        "near_clip": 1e-3, "far_clip": 1e5,
        "film": {"type": "hdrfilm", "width": w, "height": h}})
    hits = np.zeros((h, w, 3))
    valid = np.zeros((h, w), dtype=bool)
    for j in range(h):
        for i in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / w, (j + 0.5) / h),
                                       mi.Point2f(0.5, 0.5))
            si = geometry.ray_intersect(ray)
            if si.is_valid():
                hits[j, i] = [si.p[0], si.p[1], si.p[2]]
                valid[j, i] = True
    p = hits.reshape(-1, 3)
    e_perp = sheet_irradiance(e, p) * valid.reshape(-1)
    v = p - o
    z = v @ c
    cos_theta = z / np.maximum(np.linalg.norm(v, axis=1), 1e-9)
    t = np.where(valid.reshape(-1), e_perp * z * z * cos_theta / np.pi, 0.0)
    rgb = np.outer(t, np.array(e["rgb"])).reshape(h, w, 3).astype(np.float32)
    print(f"laser sheet as a projector: {w}x{h} texels, fov {fov:.3f} deg", file=sys.stderr)
    return {
        "type": "projector",
        "fov": fov,
        "fov_axis": "x",
        "to_world": to_world,
        "irradiance": {"type": "bitmap", "bitmap": mi.Bitmap(rgb), "raw": True,
                       "filter_type": "bilinear"},
    }


def render(scene, spp, seed):
    t = time.perf_counter()
    img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    return img, time.perf_counter() - t


def write_pfm(path, img):
    h, w, _ = img.shape
    with open(path, "wb") as f:
        f.write(f"PF\n{w} {h}\n-1.0\n".encode())
        f.write(np.ascontiguousarray(img[::-1], dtype="<f4").tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene_json")
    ap.add_argument("out_json")
    ap.add_argument("--spp", default="1,2,4,8,16,32,64,128,256")
    ap.add_argument("--reference-spp", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=3)
    # Stratified sub-pixel samples like stagehand's (independent is ~5x noisier here).
    ap.add_argument("--sampler", default="multijitter")
    # A GGX sample as stagehand's own sum (default) or as Mitsuba's rough plastic.
    ap.add_argument("--glossy", choices=["sum", "roughplastic"], default="sum")
    args = ap.parse_args()
    try:
        spps = sorted({int(s) for s in args.spp.split(",") if s.strip()})
    except ValueError:
        ap.error(f"--spp must be a comma-separated list of integers, got {args.spp!r}")
    if not spps or min(spps) < 1 or args.reference_spp < 1 or args.repeat < 1:
        ap.error("spp counts, --reference-spp and --repeat must be positive")

    variant = "scalar_rgb"
    mi.set_variant(variant)
    print(f"mitsuba {mi.__version__} ({variant}), numpy {np.__version__}, "
          f"python {sys.version.split()[0]}, {os.cpu_count()} cpus", file=sys.stderr)
    with open(args.scene_json) as f:
        desc = json.load(f)
    desc["sampler"] = args.sampler
    desc["glossy"] = args.glossy
    base = os.path.dirname(os.path.abspath(args.scene_json))

    t = time.perf_counter()
    scene = load_scene(desc, base)
    load_s = time.perf_counter() - t
    print(f"scene load {load_s:.3f} s", file=sys.stderr)
    render(scene, 1, 999)  # warm-up, untimed

    reference, reference_time_s = render(scene, args.reference_spp, 1_000_003)
    ref_mean = float(reference.mean())
    print(f"reference {args.reference_spp} spp: {reference_time_s:.2f} s, mean {ref_mean:.4e}",
          file=sys.stderr)
    out_dir = os.path.dirname(os.path.abspath(args.out_json))
    ref_name = "mitsuba_reference.pfm"
    write_pfm(os.path.join(out_dir, ref_name), reference)

    points = []
    for spp in spps:
        times = []
        first = None
        for r in range(args.repeat):
            img, dt = render(scene, spp, 17 + 1000 * r + spp)
            times.append(dt)
            if first is None:
                first = img
            if dt > 2.0:
                break  # long renders vary little; one is enough
        d = first - reference
        rmse = float(np.sqrt(np.mean(d * d)))
        point = {
            "spp": spp,
            "time_s": min(times),
            "times_s": times,
            "rmse": rmse,
            "rel_rmse": rmse / ref_mean if ref_mean > 0 else float("inf"),
            "max_abs": float(np.abs(d).max()),
        }
        points.append(point)
        print(f"{spp:5d} spp  {min(times) * 1e3:9.2f} ms  RMSE {rmse:.3e} "
              f"({point['rel_rmse'] * 100:.2f}%)", file=sys.stderr)

    result = {
        "renderer": "mitsuba",
        "version": mi.__version__,
        "variant": variant,
        "integrator": "path",
        "sampler": args.sampler,
        "glossy": args.glossy if desc["sample"].get("ggx") else None,
        "max_depth": int(desc["max_depth"]),
        "threads": os.cpu_count() or 0,
        "load_s": load_s,
        "reference_spp": args.reference_spp,
        "reference_time_s": reference_time_s,
        "reference_mean": ref_mean,
        "reference_image": ref_name,
        "repeat": args.repeat,
        "points": points,
    }
    with open(args.out_json, "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({"load_s": load_s, "points": len(points), "out": args.out_json}))


if __name__ == "__main__":
    main()
