"""Do two renderer builds make the same images, beyond noise? A Welch test per region.

    .venv/bin/python benchmarks/same_images.py --baseline-core OLD.so [--scene cornell]
                                               [--integrator path] [--res 64] [--spp 256] [--seeds 8]

Renders a `tessera bench` scene with this tree's core and with another build's `_core*.so`
(loaded in a child process, benchmarks/common.py LOAD_CORE), each over `--seeds` seeds,
and compares the means of a 4 x 4 grid of regions, per channel, with Welch's t-test over
the seeds (scipy). A region differs when its two-sided p-value is below 0.001 /
(regions x channels) (Bonferroni). The builds render disjoint seeds (the baseline 1..n,
this tree n+1..2n), so their noise is independent, as the test assumes. The smallest
relative difference the run detects with 90 % power is printed for the worst region
((t_crit + 1.28) standard errors of the difference): the run says nothing about smaller
ones, and "unchanged to 2 %" needs that figure at or below 2 %. The control: the same check
on the baseline's images scaled by (1 + that difference) must call the images different. Writes docs/benchmarks/same-images-<label>.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from scipy import stats

from common import LOAD_CORE, WarmChild, write_results

CHILD = LOAD_CORE + r"""
import json
import numpy as np
from tessera_tools.bench import SCENES, load_bench_scene
scenes = {}
for line in sys.stdin:
    name, integ, spp, res, seed, grid = line.split()
    spp, res, seed, grid = int(spp), int(res), int(seed), int(grid)
    if name not in scenes:
        scenes[name] = load_bench_scene(SCENES[name])
    out = scenes[name].render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2,
                                   integrator=integ)
    img = np.asarray(out, np.float64).reshape(res, res, -1)[..., :3]
    s = res // grid
    means = img[: s * grid, : s * grid].reshape(grid, s, grid, s, 3).mean(axis=(1, 3))
    print(json.dumps(means.tolist()), flush=True)
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline-core", required=True, help="a _core*.so of the build to compare against")
    ap.add_argument("--label", default="", help="names the output files (default: scene-integrator)")
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--integrator", default="path", help="one that does not splat (path, whitted, ...)")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    grid = 4
    builds = {"current": WarmChild(CHILD), "baseline": WarmChild(CHILD, os.path.abspath(args.baseline_core))}
    means = {b: [] for b in builds}
    for seed in range(1, args.seeds + 1):
        for b, child in builds.items():   # interleaved, so drift touches both alike
            own_seed = seed + (args.seeds if b == "current" else 0)
            means[b].append(child.ask(args.scene, args.integrator, args.spp, args.res, own_seed, grid))
    for child in builds.values():
        child.close()
    cur, base = (np.asarray(means[b]) for b in ("current", "baseline"))   # (seeds, grid, grid, 3)

    def welch(a, b):
        return stats.ttest_ind(a, b, axis=0, equal_var=False).pvalue

    n_tests = grid * grid * 3
    alpha = 0.001 / n_tests
    p = welch(cur, base)
    rel = cur.mean(0) / np.maximum(base.mean(0), 1e-12) - 1.0
    se = np.sqrt(cur.var(0, ddof=1) / args.seeds + base.var(0, ddof=1) / args.seeds) / np.maximum(base.mean(0), 1e-12)
    t_crit = stats.t.ppf(1.0 - alpha / 2.0, 2 * (args.seeds - 1))
    detectable = (t_crit + 1.28) * se
    differs = p < alpha
    control_scale = 1.0 + float(detectable.max())
    control = welch(base * control_scale, cur) < alpha
    label = args.label or f"{args.scene}-{args.integrator}"
    out = {"scene": args.scene, "integrator": args.integrator, "res": args.res, "spp": args.spp,
           "seeds": args.seeds, "baseline_core": os.path.basename(args.baseline_core),
           "relative_difference": rel.tolist(), "detectable": detectable.tolist(), "p": p.tolist(),
           "regions_differing": int(differs.sum()), "largest_detectable": float(detectable.max()),
           "largest_abs_difference": float(np.abs(rel).max()), "control_scale": control_scale,
           "control_regions_found": int(control.sum()), "tests": n_tests}
    lines = [f"# Same images: {label}", "",
             f"Written by `benchmarks/same_images.py`: `{args.scene}`, `{args.integrator}`, {args.res}², "
             f"{args.spp} spp, the baseline at seeds 1–{args.seeds}, this tree at {args.seeds + 1}–{2 * args.seeds}, this tree's core against "
             f"`{out['baseline_core']}`; region means of a {grid} × {grid} grid per channel, Welch's t-test over "
             f"the seeds, Bonferroni at 0.001 over {n_tests} tests.", "",
             f"- regions × channels that differ: **{out['regions_differing']} of {n_tests}**",
             f"- largest |relative difference| of a region mean: {out['largest_abs_difference']:.3%}",
             f"- smallest difference the run detects with 90 % power, worst region: "
             f"{out['largest_detectable']:.3%}",
             f"- control (the baseline scaled by {control_scale:.4f}): {out['control_regions_found']} of {n_tests} "
             "found different (the check must call the control different: at least one)", ""]
    write_results(f"same-images-{label}", out, lines)
    return 0 if out["regions_differing"] == 0 and out["control_regions_found"] > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
