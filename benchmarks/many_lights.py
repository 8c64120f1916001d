"""Many lights: next event estimation choosing among 10,000 small emitters by a light BVH
(position and orientation) against choosing by power, at equal time.

    .venv/bin/python benchmarks/many_lights.py [--res 128] [--reps 5]

Scene: tessera_tools.many_lights (10,000 one-sided emitters over a grey floor). The
reference is `path` with the BVH at 4096 spp. Each repetition renders, interleaved, both
choices at a ladder of spp with a fresh seed and records seconds and relMSE against the
reference. Error falls as 1/time for an unbiased estimator, so relMSE x seconds is the
inverse efficiency; the equal-time error ratio BVH / power is the ratio of those products
(taken per repetition and rung, median ± half-range). Also: the BVH's build time and
node count, and render seconds per sample of each. Writes docs/benchmarks/many-lights.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np
from common import OUT, fmt, rel_mse, summary

from tessera_tools.many_lights import build

LADDER = (16, 64, 256)


def render(scene, spp: int, seed: int, res: int) -> tuple[np.ndarray, float]:
    t = time.perf_counter()
    img = scene.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2, integrator="path")
    return img[..., :3], time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--lights", type=int, default=10000)
    args = ap.parse_args()
    build(args.lights, res=args.res, light_selection="power")  # warm-up: imports, first Embree device
    t = time.perf_counter()
    power = build(args.lights, res=args.res, light_selection="power")
    t_power_build = time.perf_counter() - t
    t = time.perf_counter()
    bvh = build(args.lights, res=args.res, light_selection="bvh")
    t_bvh_build = time.perf_counter() - t
    ref, t_ref = render(bvh, 4096, 987654, args.res)
    print(f"reference: 4096 spp in {t_ref:.1f} s", flush=True)
    rows = []
    for rep in range(args.reps):
        for spp in LADDER:
            row = {"rep": rep, "spp": spp}
            for name, scene in (("power", power), ("bvh", bvh)):
                img, seconds = render(scene, spp, 1000 * rep + spp, args.res)
                row[name] = {"seconds": seconds, "rel_mse": float(rel_mse(img, ref))}
            row["equal_time_error_ratio"] = (row["bvh"]["rel_mse"] * row["bvh"]["seconds"]) / \
                                            (row["power"]["rel_mse"] * row["power"]["seconds"])
            rows.append(row)
            print(row, flush=True)
    ratio = summary([r["equal_time_error_ratio"] for r in rows])
    per_rung = {spp: summary([r["equal_time_error_ratio"] for r in rows if r["spp"] == spp]) for spp in LADDER}
    cost = {name: summary([r[name]["seconds"] / (r["spp"] * args.res * args.res) * 1e9 for r in rows])
            for name in ("power", "bvh")}
    out = {"lights": args.lights, "res": args.res, "reps": args.reps, "ladder": LADDER, "threads": 2,
           "scene_build_seconds": {"power": t_power_build, "bvh": t_bvh_build},
           "equal_time_error_ratio": ratio, "per_rung": {str(k): v for k, v in per_rung.items()},
           "ns_per_sample": cost, "rows": rows, "load_average": os.getloadavg()[0]}
    lines = ["# Many lights: light BVH against power-proportional choice", "",
             f"Written by `benchmarks/many_lights.py`: {args.lights} small one-sided emitters over a grey floor "
             f"(`tessera_tools.many_lights`), `path`, {args.res}x{args.res}, 2 threads, spp ladder {LADDER}, "
             f"{args.reps} interleaved repetitions; reference: `path` with the BVH at 4096 spp. relMSE falls as "
             "1/time, so the equal-time error ratio is (relMSE x seconds) with the BVH over the same by power, "
             "per repetition and rung; median ± half-range.", "",
             f"- **Equal-time error, BVH / power: {fmt(ratio)}** (target: at most 1/3)"]
    lines += [f"  - at {spp} spp: {fmt(per_rung[spp])}" for spp in LADDER]
    lines += [f"- Render cost per sample: power {fmt(cost['power'], ' ns')}, BVH {fmt(cost['bvh'], ' ns')}",
              f"- Scene build (Embree BVH + light tables): power {t_power_build:.3f} s, with the light BVH "
              f"{t_bvh_build:.3f} s", "",
              f"Load average at the start: {out['load_average']:.2f} (2 shared vCPUs)."]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "many-lights.json").write_text(json.dumps(out, indent=2) + "\n")
    (OUT / "many-lights.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
