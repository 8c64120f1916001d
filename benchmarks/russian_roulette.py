"""Where the path tracer's Russian roulette should start: error per time, per start vertex.

    .venv/bin/python benchmarks/russian_roulette.py [--res 64] [--spp 128] [--seeds 4] [--reps 3]
                                                     [--depths 2,3,4,5,6]

Russian roulette (`path`'s setting `rr_depth`: the vertex index from which it may end a
path) trades error for time: an earlier start ends paths sooner, and its coin flips add
noise. Which way the trade goes is measured here, per scene, by the efficiency
1 / (relMSE x seconds), i.e. the inverse of the time to a given error (relMSE falls as
1/time for a fixed rr_depth).

Per scene: a reference of 2 x 4096 spp (path, rr_depth 5; its own relMSE, estimated from
the two halves, is subtracted from every measurement), then `--reps` repetitions, each
rendering every rr_depth in turn (interleaved) with `--seeds` seeds of `--spp` samples at
`--res`² on 2 threads in this process. relMSE is the bench's (tessera_tools.bench_stats).
Reports median ± half-range over repetitions of seconds, relMSE and the efficiency
relative to rr_depth 2 (the start before 2026-12-07) within each repetition. Writes
docs/benchmarks/russian-roulette.{md,json}.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from common import fmt, summary, write_results

from tessera_tools.bench import SCENES, load_bench_scene
from tessera_tools.bench_stats import reference_noise, rel_mse

SCENE_NAMES = ("cornell-lambert", "cornell", "dome-glass")


def render(scene, res: int, spp: int, seed: int, rr_depth: int) -> np.ndarray:
    img = scene.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2, max_depth=64,
                            integrator="path", integrator_params={"rr_depth": float(rr_depth)})
    return np.asarray(img)[..., :3].astype(np.float64)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--depths", default="2,3,4,5,6")
    ap.add_argument("--scenes", default=",".join(SCENE_NAMES))
    args = ap.parse_args()
    depths = [int(d) for d in args.depths.split(",")]
    base = depths[0]
    data = {"res": args.res, "spp": args.spp, "seeds": args.seeds, "reps": args.reps, "scenes": {}}
    rows = []
    for name in args.scenes.split(","):
        scene = load_bench_scene(SCENES[name])
        halves = [render(scene, args.res, 4096, 900001 + k, 5) for k in range(2)]
        ref = (halves[0] + halves[1]) / 2
        own, _ = reference_noise(*halves)
        per = {d: {"seconds": [], "relmse": [], "efficiency_vs_base": []} for d in depths}
        for rep in range(args.reps):
            eff = {}
            for d in depths:
                t = time.perf_counter()
                imgs = [render(scene, args.res, args.spp, 1000 * rep + s, d) for s in range(args.seeds)]
                seconds = (time.perf_counter() - t) / args.seeds
                err = float(np.mean([rel_mse(img, ref) for img in imgs])) - own
                per[d]["seconds"].append(seconds)
                per[d]["relmse"].append(err)
                eff[d] = 1.0 / (err * seconds)
            for d in depths:
                per[d]["efficiency_vs_base"].append(eff[d] / eff[base])
            print(f"{name} repetition {rep + 1}/{args.reps} done", flush=True)
        data["scenes"][name] = {"reference_own_relmse": own, "by_rr_depth": {str(d): per[d] for d in depths}}
        for d in depths:
            rows.append(f"| {name} | {d} | {fmt(summary(per[d]['seconds']), ' s')} | "
                        f"{fmt(summary(per[d]['relmse']))} | {fmt(summary(per[d]['efficiency_vs_base']), '×')} |")
    lines = ["# Where Russian roulette starts (`path`, `rr_depth`)", "",
             f"Written by `benchmarks/russian_roulette.py`: {args.res}² px, {args.spp} spp, {args.seeds} seeds per "
             f"setting, {args.reps} interleaved repetitions, 2 threads, max depth 64; median ± half-range over "
             "repetitions. Seconds are per render; relMSE is against a 2 × 4096 spp reference with the "
             "reference's own relMSE subtracted; efficiency = 1 / (relMSE × seconds), relative to "
             f"rr_depth {base} within each repetition (above 1: less time to the same error).", "",
             "| scene | rr_depth | seconds per render | relMSE | efficiency vs rr_depth " + str(base) + " |",
             "|---|---|---|---|---|", *rows, ""]
    write_results("russian-roulette", data, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
