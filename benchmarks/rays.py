"""Rays per second: the renderer's integrators against raw Embree on the same scene.

    .venv/bin/python benchmarks/rays.py [--res 128] [--spp 16] [--runs 5]

For each scene, one run is:
1. the path integrator renders the image on 2 threads; RenderStats counts the Embree
   queries it made (closest-hit rtcIntersect1 and shadow rtcOccluded1, per thread), so
   renderer rays/s = (closest + shadow) / wall time of the render call;
2. raw Embree (`_core.trace_rays`: a loop of rtcIntersect1 / rtcOccluded1 over the
   scene's own BVH on 2 threads, nothing else) casts the same numbers of rays: one
   coherent camera ray per pixel sample (row-major pixels, jittered), the remaining
   closest-hit rays as incoherent bounce rays (from area-uniform surface points into a
   cosine-distributed hemisphere on a random side), and the shadow rays as segments
   between two random surface points. raw rays/s = all rays / the sum of the three
   casting times.
The ratio renderer / raw is what the renderer keeps of Embree's ceiling: the rest goes to
shading, sampling, light selection and bookkeeping. The same raw rays are also cast
through Embree's other interfaces (`trace_rays(interface=...)`): packets of 8 consecutive
rays (rtcIntersect8 / rtcOccluded8; camera rays with the COHERENT hint, which suits them)
and streams of 256 (rtcIntersect1M / rtcOccluded1M), with the hit counts checked equal to
the single rays'. Median ± half-range over the runs (benchmarks/common.py). Writes
docs/benchmarks/rays.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np
from common import CORNELL, OUT, REPO, fmt, summary

SHARED = REPO.parent / "shared" / "scenes"
INTERFACES = ("packet8", "stream")
KINDS = ("primary", "bounce", "shadow")
# Its own camera and a RectLight (frame 27, as tests/renderer/usd/test_real_scenes.py renders it).
REAL = ("arnoldusd_disk_rect_lights", "test_2439.5/data/rect.usda")


def camera_rays(scene, width: int, height: int, spp: int, rng) -> tuple[np.ndarray, np.ndarray]:
    c = scene.data.camera
    tan_w, tan_h = c.tan_half_angles(width, height)
    fwd, right, up = (np.asarray(v, np.float64) for v in (c.forward, c.right, c.up))
    py, px = np.divmod(np.repeat(np.arange(width * height), spp), width)
    sx = (2 * (px + rng.random(px.size)) / width - 1) * tan_w
    sy = (1 - 2 * (py + rng.random(py.size)) / height) * tan_h
    d = fwd + right * sx[:, None] + up * sy[:, None]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(np.asarray(c.origin, np.float64), d.shape)
    return o.astype(np.float32), d.astype(np.float32)


def surface_points(scene, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform points on the scene's triangles and their unit normals."""
    p = scene.data.positions.reshape(-1, 3).astype(np.float64)
    tri = scene.data.indices.reshape(-1, 3)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    pick = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    pts = a[pick] + (b - a)[pick] * u[:, None] + (c - a)[pick] * v[:, None]
    return pts, cross[pick] / area[pick, None]


def bounce_rays(scene, n: int, rng, eps: float) -> tuple[np.ndarray, np.ndarray]:
    pts, nrm = surface_points(scene, n, rng)
    nrm *= np.where(rng.random(n) < 0.5, -1.0, 1.0)[:, None]
    # cosine-weighted hemisphere around nrm
    r, phi = np.sqrt(rng.random(n)), 2 * math.pi * rng.random(n)
    t1 = np.cross(nrm, np.where(np.abs(nrm[:, :1]) > 0.9, [[0.0, 1, 0]], [[1.0, 0, 0]]))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    d = t1 * (r * np.cos(phi))[:, None] + t2 * (r * np.sin(phi))[:, None] + nrm * np.sqrt(1 - r * r)[:, None]
    return (pts + nrm * eps).astype(np.float32), (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def shadow_rays(scene, n: int, rng, eps: float):
    p0, n0 = surface_points(scene, n, rng)
    p1, _ = surface_points(scene, n, rng)
    d = p1 - p0
    dist = np.linalg.norm(d, axis=1)
    d /= np.maximum(dist, 1e-12)[:, None]
    o = p0 + n0 * np.where((d * n0).sum(1) < 0, -eps, eps)[:, None]
    return o.astype(np.float32), d.astype(np.float32), (dist * (1 - 1e-4)).astype(np.float32)


def one_run(scene, res: int, spp: int, seed: int) -> dict:
    from tessera_renderer import _core

    stats: dict = {}
    start = time.perf_counter()
    scene.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2, stats=stats)
    seconds = time.perf_counter() - start
    closest, shadow = int(stats["closest_rays"]), int(stats["shadow_rays"])
    rng = np.random.default_rng(seed)
    eps = 1e-4 * float(np.ptp(scene.data.positions.reshape(-1, 3), axis=0).max())
    primary = res * res * spp
    kinds = {"primary": (*camera_rays(scene, res, res, spp, rng), None, False),
             "bounce": (*bounce_rays(scene, max(closest - primary, 0), rng, eps), None, False),
             "shadow": (*shadow_rays(scene, shadow, rng, eps), True)}
    times, other = {}, {}
    for kind, (o, d, tf, occluded) in kinds.items():
        tf = np.full(len(o), np.inf, np.float32) if tf is None else tf
        hits, times[kind] = _core.trace_rays(scene._core, o, d, tf, occluded, 2)
        for interface in INTERFACES:
            h, t = _core.trace_rays(scene._core, o, d, tf, occluded, 2, interface, kind == "primary")
            if h != hits:
                raise SystemExit(f"{kind} rays: {interface} found {h} hits, single rays {hits}")
            other[f"raw_{kind}_{interface}_mrays"] = len(o) / t / 1e6 if t > 0 else 0.0
    t_primary, t_bounce, t_shadow = times["primary"], times["bounce"], times["shadow"]
    raw_seconds = t_primary + t_bounce + t_shadow
    total = closest + shadow
    return {"render_seconds": seconds, "closest_rays": closest, "shadow_rays": shadow, "primary_rays": primary,
            "renderer_mrays": total / seconds / 1e6, "raw_mrays": total / raw_seconds / 1e6,
            "raw_primary_mrays": primary / t_primary / 1e6,
            "raw_bounce_mrays": (closest - primary) / t_bounce / 1e6 if t_bounce > 0 else 0.0,
            "raw_shadow_mrays": shadow / t_shadow / 1e6 if t_shadow > 0 else 0.0,
            "ratio": (total / seconds) / (total / raw_seconds), **other}


def main() -> int:
    from tessera_renderer import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    # The box as exporters write it (UsdPreviewSurface turned Lambertian at load): the lane
    # kernel's scene (docs/benchmarks/simd-kernel.md), its rays those of the Lambertian kernel.
    scenes = [("cornell", lambda: load_scene(CORNELL)),
              ("cornell_exported", lambda: load_scene(CORNELL.with_name("cornell_exported.usda")))]
    real = SHARED / REAL[0] / REAL[1]
    if real.is_file():
        scenes.append((f"{REAL[0]}/{REAL[1]}", lambda: load_scene(real, frame=27, root=SHARED / REAL[0])))
    else:
        print(f"warning: {real} is missing; only the Cornell box", file=sys.stderr)
    out = {"res": args.res, "spp": args.spp, "runs": args.runs, "threads": 2, "integrator": "path",
           "load_average": os.getloadavg()[0], "scenes": {}}
    lines = ["# Rays per second: renderer vs raw Embree", "",
             f"Written by `benchmarks/rays.py`: path integrator, {args.res}x{args.res}, {args.spp} spp, 2 threads; "
             f"{args.runs} runs, median ± half-range. Load average at the start: {out['load_average']:.2f} "
             "(2 shared vCPUs).", "",
             "| scene | triangles | rays per run (closest + shadow) | renderer Mrays/s | raw Embree Mrays/s "
             "| renderer / raw |", "|---|---|---|---|---|---|"]
    for name, load in scenes:
        scene = load()
        one_run(scene, 16, 1, 999)  # warm up (first-touch of the BVH, thread pool)
        runs = [one_run(scene, args.res, args.spp, seed) for seed in range(args.runs)]
        s = {k: summary([r[k] for r in runs]) for k in ("renderer_mrays", "raw_mrays", "ratio",
                                                         "raw_primary_mrays", "raw_bounce_mrays",
                                                         "raw_shadow_mrays")}
        for kind in KINDS:
            for interface in INTERFACES:
                key = f"raw_{kind}_{interface}_mrays"
                s[key] = summary([r[key] for r in runs])
                s[f"{kind}_{interface}_over_single"] = summary(
                    [r[key] / r[f"raw_{kind}_mrays"] for r in runs])
        out["scenes"][name] = {"triangles": scene.num_triangles, "runs": runs, **s}
        r0 = runs[0]
        lines.append(f"| {name} | {scene.num_triangles} | {r0['closest_rays']} + {r0['shadow_rays']} "
                     f"({r0['primary_rays']} camera) | {fmt(s['renderer_mrays'])} | {fmt(s['raw_mrays'])} "
                     f"| {fmt(s['ratio'])} |")
        print(lines[-1], flush=True)
    lines += ["", "How: the renderer's rays are the Embree queries the integrator made (RenderStats counters, "
              "per thread), over the wall time of the render call. Raw Embree casts the same numbers of "
              "rays with `_core.trace_rays`: a bare rtcIntersect1 / rtcOccluded1 loop over the same BVH on "
              "2 threads. It casts one jittered camera ray per pixel sample, the other closest-hit rays "
              "as bounce rays from area-uniform surface points (cosine hemisphere, random side), and the "
              "shadow rays as segments between random surface points. The raw rays are synthetic, so "
              "their mix of hits and misses is close to the renderer's but not identical. The ratio is "
              "the share of Embree's ceiling the renderer keeps; the rest of its time goes to shading, "
              "BSDF and light sampling, the sampler and bookkeeping.",
              "", "Raw Embree by ray kind (Mrays/s, same runs):", "",
              "| scene | camera (coherent) | bounce (incoherent) | shadow (incoherent segments) |",
              "|---|---|---|---|"]
    for name, s in out["scenes"].items():
        lines.append(f"| {name} | {fmt(s['raw_primary_mrays'])} | {fmt(s['raw_bounce_mrays'])} "
                     f"| {fmt(s['raw_shadow_mrays'])} |")
    lines += ["", "Embree's packet and stream interfaces on the same rays, as a speed ratio to single rays "
              "(same runs; camera rays with the COHERENT hint, the others INCOHERENT; hit counts equal):", "",
              "| scene | interface | camera | bounce | shadow |", "|---|---|---|---|---|"]
    for name, s in out["scenes"].items():
        for interface in INTERFACES:
            lines.append(f"| {name} | {interface} | " + " | ".join(
                fmt(s[f"{kind}_{interface}_over_single"]) for kind in KINDS) + " |")
    lines += ["", "What the best interface per ray kind would buy, from the medians: the raw casting "
              "time it saves, and, since Embree's share of the render is about the renderer / raw ratio, "
              "the share of the render's time that is:", ""]
    for name, s in out["scenes"].items():
        r0 = s["runs"][0]
        counts = {"primary": r0["primary_rays"], "bounce": r0["closest_rays"] - r0["primary_rays"],
                  "shadow": r0["shadow_rays"]}
        single = sum(counts[k] / s[f"raw_{k}_mrays"]["median"] for k in KINDS)
        best = sum(counts[k] / (s[f"raw_{k}_mrays"]["median"] * max(
            [1.0] + [s[f"{k}_{i}_over_single"]["median"] for i in INTERFACES])) for k in KINDS)
        saved = 1 - best / single
        s["best_interface_saves_raw"] = saved
        s["best_interface_saves_render"] = saved * s["ratio"]["median"]
        lines.append(f"- {name}: {100 * saved:.0f} % of Embree's time, about "
                     f"{100 * saved * s['ratio']['median']:.1f} % of the render's.")
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "rays.json").write_text(json.dumps(out, indent=2) + "\n")
    (OUT / "rays.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
