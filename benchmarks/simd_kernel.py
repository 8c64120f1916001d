"""The lane-group path kernel (renderer/core/integrators/path_lanes.h) against the scalar
kernel on the Cornell box as exporters write it.

    .venv/bin/python benchmarks/simd_kernel.py [--res 128] [--spp 64] [--runs 7]

`path`'s setting `lanes` picks the kernel in the same build: 0 the scalar kernel, 1 / 4 / 8
the lane kernel with single rays / rtcIntersect4 / rtcIntersect8 packets for its closest
hits. One run renders the image once with each, in turn (interleaved, so the machine's load
drifts over all of them alike), on 2 threads in one warm process; each kernel's time is
divided by the scalar kernel's of the same run. Wall time and the process's CPU time (both
threads; steadier than wall time when other processes share the cores) are both kept. The images are checked equal to the bit.
Median ± half-range over the runs (common.py). Writes docs/benchmarks/simd-kernel.{md,json}.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
from common import CORNELL, fmt, summary, write_results

SCENE = CORNELL.with_name("cornell_exported.usda")
KERNELS = {"scalar": 0, "lanes 8": 8, "lanes 4": 4, "lanes 1": 1}


def main() -> int:
    from tessera_renderer import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    scene = load_scene(SCENE)
    render = lambda lanes, spp: scene.render_tile(0, 0, args.res, args.res, width=args.res, height=args.res,
                                                   spp=spp, threads=2, integrator="path",
                                                   integrator_params={"lanes": lanes})
    for lanes in KERNELS.values():
        render(lanes, 1)  # warm up: BVH first touch, thread pool
    load = os.getloadavg()[0]
    times = {k: [] for k in KERNELS}
    cpu = {k: [] for k in KERNELS}
    for run in range(args.runs):
        images = {}
        for name, lanes in KERNELS.items():
            t0, c0 = time.perf_counter(), time.process_time()
            images[name] = render(lanes, args.spp)
            times[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
        for name, img in images.items():
            if not np.array_equal(img.view(np.uint32), images["scalar"].view(np.uint32)):
                raise SystemExit(f"run {run}: the {name} kernel's image differs from the scalar kernel's")
    ratios = {k: summary([a / b for a, b in zip(v, times["scalar"])]) for k, v in times.items()}
    secs = {k: summary(v) for k, v in times.items()}
    cpu_ratios = {k: summary([a / b for a, b in zip(v, cpu["scalar"])]) for k, v in cpu.items()}
    cpu_secs = {k: summary(v) for k, v in cpu.items()}
    data = {"scene": str(SCENE.relative_to(CORNELL.parents[2])), "res": args.res, "spp": args.spp,
            "runs": args.runs, "threads": 2, "load_average": load, "seconds": secs, "ratio_to_scalar": ratios,
            "cpu_seconds": cpu_secs, "cpu_ratio_to_scalar": cpu_ratios}
    lines = ["# The lane-group path kernel against the scalar kernel", "",
             f"Written by `benchmarks/simd_kernel.py`: `{data['scene']}`, {args.res}x{args.res}, {args.spp} spp, "
             f"2 threads, {args.runs} interleaved runs, median ± half-range; load average at the start "
             f"{load:.2f} (2 shared vCPUs). Every run's images are equal to the bit.", "",
             "| kernel | wall s per render | wall time / scalar's (same run) | CPU s per render "
             "| CPU time / scalar's (same run) |", "|---|---|---|---|---|"]
    for k in KERNELS:
        lines.append(f"| {k} | {fmt(secs[k], ' s')} | {fmt(ratios[k])} | {fmt(cpu_secs[k], ' s')} "
                     f"| {fmt(cpu_ratios[k])} |")
    write_results("simd-kernel-runs", data, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
