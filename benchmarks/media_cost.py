"""What participating-media support costs a scene without media: this tree's renderer
against a build from before media existed, on the path tracer, in one interleaved run.

    .venv/bin/python benchmarks/media_cost.py --baseline-core /path/to/_core.so [--reps 7]

The baseline is a `_core*.so` built from the commit before media (tessera_renderer's
module, kept aside before rebuilding). Each side is a warm child process (LOAD_CORE);
per repetition each renders each scene once, sides alternating (A B, B A, ...), and the
images must be the same to the bit (SHA-256 of the RGBA). Ratio = this build's time over
the baseline's, per repetition, median ± half-range. Written to docs/benchmarks/media-cost.{md,json}.
"""
from __future__ import annotations

import argparse
import os
import sys

from common import LOAD_CORE, WarmChild, fmt, summary, write_results

# cornell-lambert runs the Lambertian kernel, cornell-exported the general BSDF one.
SCENES = ("cornell-lambert", "cornell-exported")

CHILD = LOAD_CORE + r"""
import hashlib, json, time
from tessera_tools.bench import SCENES, load_bench_scene
scenes = {}
for line in sys.stdin:
    name, spp, res = line.split()
    spp, res = int(spp), int(res)
    if name not in scenes:
        scenes[name] = load_bench_scene(SCENES[name])
        scenes[name].render_tile(0, 0, 8, 8, width=8, height=8, spp=1, seed=0, threads=2, integrator="path")
    t = time.perf_counter()
    rgba = scenes[name].render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=1, threads=2,
                                    integrator="path")
    seconds = time.perf_counter() - t
    print(json.dumps({"seconds": seconds, "sha256": hashlib.sha256(rgba.tobytes()).hexdigest()}), flush=True)
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline-core", required=True, help="a _core*.so built before media support")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--reps", type=int, default=7)
    args = ap.parse_args()
    sides = {"baseline": WarmChild(CHILD, os.path.abspath(args.baseline_core)), "current": WarmChild(CHILD)}
    for child in sides.values():
        for name in SCENES:
            child.ask(name, 1, 16)
    times = {name: {s: [] for s in sides} for name in SCENES}
    ratios = {name: [] for name in SCENES}
    for rep in range(args.reps):
        order = list(sides) if rep % 2 == 0 else list(sides)[::-1]
        for name in SCENES:
            got = {s: sides[s].ask(name, args.spp, args.res) for s in order}
            if got["baseline"]["sha256"] != got["current"]["sha256"]:
                sys.exit(f"{name}: the two builds' images differ")
            for s in sides:
                times[name][s].append(got[s]["seconds"])
            ratios[name].append(got["current"]["seconds"] / got["baseline"]["seconds"])
            print(name, rep, {s: round(got[s]["seconds"], 3) for s in sides}, flush=True)
    for child in sides.values():
        child.close()
    out = {"res": args.res, "spp": args.spp, "reps": args.reps, "threads": 2, "load_average": os.getloadavg()[0],
           "scenes": {n: {"baseline": summary(times[n]["baseline"]), "current": summary(times[n]["current"]),
                          "ratio": summary(ratios[n])} for n in SCENES}}
    lines = ["# Scenes without media and media support", "",
             f"Written by `benchmarks/media_cost.py`: `path`, {args.res}x{args.res}, {args.spp} spp, 2 threads, "
             f"{args.reps} interleaved repetitions in two warm processes, median ± half-range. The baseline is the "
             "core built before media support; every pair of images is identical to the bit. Ratio = this build's "
             "time / the baseline's per repetition (1: media support costs nothing).", "",
             "| scene | baseline s | with media support s | ratio |", "|---|---|---|---|"]
    for n in SCENES:
        s = out["scenes"][n]
        lines.append(f"| {n} | {fmt(s['baseline'])} | {fmt(s['current'])} | {fmt(s['ratio'])} |")
    lines += ["", f"Load average at the end: {out['load_average']:.2f} (2 shared vCPUs)."]
    write_results("media-cost", out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
