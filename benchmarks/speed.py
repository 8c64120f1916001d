"""Per-sample cost: Tessera's path and bdpt against Mitsuba 3 (llvm_ad_rgb path), interleaved.

    .venv/bin/python benchmarks/speed.py [--res 256] [--spp 64] [--reps 5] [--baseline-core OLD.so]

One repetition renders, back to back and in the same process order every time, each scene
with Mitsuba's llvm path tracer, Tessera `path` at the same spp and Tessera `bdpt` at a
quarter of it (BDPT's samples cost several path samples; the ratio is per sample). Each
Tessera render runs in a warm child process per renderer build (the scene loaded once), so
`--baseline-core` (a `_core*.so` of an older build) measures the current build against that
one in the same interleaved run. Scenes: `cornell-exported` (the Cornell box as exporters
write a plain diffuse UsdPreviewSurface, rendered as authored), `cornell-lambert` (the
authored box with Lambertian materials, the one Mitsuba matches) and `caustic` (glass sphere, small sphere light), as
`tessera bench` translates them for Mitsuba. Reports median ± half-range of the seconds and
of each ratio (ratios are taken within a repetition), plus the Embree rays each Tessera
sample cast. Writes docs/benchmarks/speed.{md,json}.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from common import LOAD_CORE, WarmChild, fmt, summary, write_results

SCENES = ("cornell-exported", "cornell-lambert", "caustic")

CHILD = LOAD_CORE + r"""
import json, time
import numpy as np
from tessera_tools.bench import SCENES, load_bench_scene
scenes = {}
for line in sys.stdin:
    name, integ, spp, res, seed = line.split()
    spp, res, seed = int(spp), int(res), int(seed)
    if name not in scenes:
        scenes[name] = load_bench_scene(SCENES[name])
        scenes[name].render_tile(0, 0, 8, 8, width=8, height=8, spp=1, seed=0, threads=2, integrator="path")
    sc, stats = scenes[name], {}
    splats = np.zeros((res, res, 3), np.int64) if integ in ("bdpt", "light") else None
    t = time.perf_counter()
    sc.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2, integrator=integ,
                   stats=stats, splats=splats)
    seconds = time.perf_counter() - t
    print(json.dumps({"seconds": seconds, "samples": stats["samples"], "closest": stats["closest_rays"],
                      "shadow": stats["shadow_rays"]}), flush=True)
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--baseline-core", default="", help="a _core*.so of another build, timed in the same run")
    args = ap.parse_args()

    from tessera_tools.bench import SCENES as BENCH, Config, MitsubaPeer, load_bench_scene

    builds = {"current": WarmChild(CHILD)}
    if args.baseline_core:
        builds["baseline"] = WarmChild(CHILD, os.path.abspath(args.baseline_core))
    peer = MitsubaPeer("llvm_ad_rgb", 2)
    cfg = Config(res=args.res)
    for name in SCENES:
        peer.load(name, load_bench_scene(BENCH[name]).data, args.res, cfg)
        peer.render(name, 4, 0)  # JIT compilation happens here, not in the timed renders
        for child in builds.values():
            child.ask(name, "path", 1, 16, 0)
    bdpt_spp = max(1, args.spp // 4)
    rows: dict = {name: [] for name in SCENES}
    for rep in range(args.reps):
        for name in SCENES:
            t = time.perf_counter()
            peer.render(name, args.spp, rep + 1)
            row = {"mitsuba": time.perf_counter() - t}
            for label, child in builds.items():
                row[f"{label} path"] = child.ask(name, "path", args.spp, args.res, rep + 1)
                row[f"{label} bdpt"] = child.ask(name, "bdpt", bdpt_spp, args.res, rep + 1)
            rows[name].append(row)
            print(name, rep, {k: (v if isinstance(v, float) else v["seconds"]) for k, v in row.items()}, flush=True)
    for child in builds.values():
        child.close()

    out = {"res": args.res, "spp": args.spp, "bdpt_spp": bdpt_spp, "reps": args.reps, "threads": 2,
           "mitsuba": peer.version, "load_average": os.getloadavg()[0], "scenes": {}}
    lines = ["# Per-sample cost against Mitsuba 3", "",
             f"Written by `benchmarks/speed.py`: {args.res}x{args.res}, 2 threads, Mitsuba {peer.version} "
             f"llvm_ad_rgb path at {args.spp} spp, Tessera `path` at {args.spp} spp and `bdpt` at {bdpt_spp} spp; "
             f"{args.reps} interleaved repetitions, median ± half-range. A ratio is Tessera's time per sample over "
             "Mitsuba path's, taken within each repetition (below 1: Tessera is faster). Render calls only: "
             "process start, scene load and Mitsuba's JIT compilation are outside the timings.", ""]
    per_sample = lambda r, key, spp: r[key]["seconds"] / spp / (r["mitsuba"] / args.spp)  # noqa: E731
    header = "| scene | Mitsuba llvm path s | " + " | ".join(
        f"{b} path s | {b} path / Mitsuba per sample | {b} bdpt / Mitsuba per sample | {b} bdpt / path per sample"
        for b in builds) + " | rays per sample (closest + shadow): path, bdpt |"
    lines += [header, "|" + "---|" * (header.count("|") - 1)]
    for name, rs in rows.items():
        s = {"mitsuba_seconds": summary([r["mitsuba"] for r in rs])}
        cells = [fmt(s["mitsuba_seconds"], "", 3)]
        for b in builds:
            s[f"{b}_path_seconds"] = summary([r[f"{b} path"]["seconds"] for r in rs])
            s[f"{b}_path_vs_mitsuba"] = summary([per_sample(r, f"{b} path", args.spp) for r in rs])
            s[f"{b}_bdpt_vs_mitsuba"] = summary([per_sample(r, f"{b} bdpt", bdpt_spp) for r in rs])
            s[f"{b}_bdpt_vs_path"] = summary([(r[f"{b} bdpt"]["seconds"] / bdpt_spp) /
                                              (r[f"{b} path"]["seconds"] / args.spp) for r in rs])
            cells += [fmt(s[f"{b}_path_seconds"]), fmt(s[f"{b}_path_vs_mitsuba"]), fmt(s[f"{b}_bdpt_vs_mitsuba"]),
                      fmt(s[f"{b}_bdpt_vs_path"])]
        r0 = rs[0]["current path"], rs[0]["current bdpt"]
        rays = [(r["closest"] / r["samples"], r["shadow"] / r["samples"]) for r in r0]
        s["rays_per_sample"] = {"path": rays[0], "bdpt": rays[1]}
        cells.append(f"{rays[0][0]:.2f} + {rays[0][1]:.2f}, {rays[1][0]:.2f} + {rays[1][1]:.2f}")
        out["scenes"][name] = {"summary": s, "runs": rs}
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if args.baseline_core:
        lines += ["", "`baseline` is the renderer build given by `--baseline-core`, timed in the same run; "
                  "`current` is this tree's. Speed-up of this build over the baseline, per repetition:", ""]
        for name, rs in rows.items():
            for integ in ("path", "bdpt"):
                sp = summary([r[f"baseline {integ}"]["seconds"] / r[f"current {integ}"]["seconds"] for r in rs])
                out["scenes"][name]["summary"][f"speedup_{integ}"] = sp
                lines.append(f"- {name} `{integ}`: {fmt(sp, '×')}")
    lines += ["", f"Load average at the start: {out['load_average']:.2f} (2 shared vCPUs)."]
    write_results("speed", out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
