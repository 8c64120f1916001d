"""What a local render's noise layer costs the splatting integrators (light, bdpt, vcm).

    .venv/bin/python benchmarks/variance_batches.py [--res 128] [--reps 5]

A splatting integrator's variance comes from convergence.VARIANCE_BATCHES batches of each
pass's samples, each a whole image. `tessera render` makes them by default. Ways of
rendering the same image with `tessera.local.render_image` on 2 threads (and one of
them without its noise layer, both ways), interleaved within each repeat in one warm
process:
- `image`: variance=False, the image alone (what the noise layer is measured against);
- `one pass` (this tree): the batches come from the pass's own render call, each sample's
  splats and camera mean routed to its batch (render.h VarianceBatches), the splats added
  straight into the job's sums (render_tile_pass `into`);
- `re-render` (the baseline, the way before 2026-12-07, kept here as it was): the pass
  is rendered, then every batch's sample range again, one render call per batch, each
  with its own full-frame splat buffer, folded into the job's sums tile by tile.
`image` is this tree's image without a noise layer; `image, folded` the same the way
before (a full-frame splat buffer per tile, folded), so that both ways' costs can be read
against either.
Every repeat checks that the four images and the two ways' noise layers are the same to
the bit. Cost = time / the image's time (this tree's), median ± half-range over repeats. Writes
docs/benchmarks/variance-batches.{md,json}.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from common import CORNELL, REPO, fmt, summary, write_results

CAUSTIC = REPO / "examples" / "caustic" / "caustic.usda"
CASES = [("cornell", CORNELL, "bdpt", 16), ("cornell", CORNELL, "light", 16),
         ("caustic", CAUSTIC, "bdpt", 16), ("caustic", CAUSTIC, "vcm", 16)]


def rerender_tile_pass(scene, settings, rect, pass_index, *, integrator, threads=0, variance=False,
                       batches=False, scene_product=None, into=None):
    """The baseline: the pass without batches, then each batch's range rendered again, each
    into a full-frame buffer of its own, folded into the job's sums (`into`) afterwards."""
    from tessera_base import film
    from tessera_base.convergence import batch_ranges
    from tessera_base.protocol import SplatBatch, pass_range

    result, seconds = film.render_tile_pass(scene, settings, rect, pass_index, integrator=integrator,
                                            threads=threads, variance=variance, scene_product=scene_product)
    started = time.perf_counter()
    if not batches:
        return into.fold(result), seconds + time.perf_counter() - started
    sample_start, spp = pass_range(settings, pass_index)
    result.batches = []
    for start, n in batch_ranges(sample_start, spp):
        buf = np.zeros((settings.height, settings.width, 3), np.int64)
        cam = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height, width=settings.width,
                                height=settings.height, spp=n, sample_start=start, seed=settings.seed,
                                max_depth=settings.max_depth, threads=threads, integrator=integrator,
                                integrator_params=dict(settings.integrator_params), splats=buf,
                                scene_product=scene_product)
        b_rect, b_layer = film.splat_layer(buf)
        result.batches.append(SplatBatch(n, np.ascontiguousarray(cam[..., :3]), b_rect, b_layer,
                                         rect.width * rect.height * n))
    return into.fold(result), seconds + time.perf_counter() - started


def timed(scene, settings, way: str):
    from tessera import local

    local.render_tile_pass = rerender_tile_pass if way in ("re-render", "image, folded") else ORIGINAL
    try:
        t = time.perf_counter()
        out = local.render_image(scene, settings, threads=2, progress=False,
                                 variance=way in ("one pass", "re-render"))
        return time.perf_counter() - t, out
    finally:
        local.render_tile_pass = ORIGINAL


def main() -> int:
    global ORIGINAL
    from tessera import local
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    ORIGINAL = local.render_tile_pass
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    ways = ("image", "one pass", "re-render", "image, folded")
    out = {"res": args.res, "reps": args.reps, "threads": 2, "tile_size": 64,
           "load_average": os.getloadavg()[0], "cases": {}}
    lines = ["# What a local render's noise layer costs the splatting integrators", "",
             f"Written by `benchmarks/variance_batches.py`: `tessera.local.render_image`, {args.res} x "
             f"{args.res}, tiles of 64, 2 threads, {args.reps} interleaved repeats in one warm process "
             f"(load average at the start {out['load_average']:.2f}). Cost = seconds / the image's "
             "seconds without a noise layer, median ± half-range. `one pass`: this tree, the batches "
             "made in the pass's own render call and every splat added straight into the job's sums; "
             "`re-render`: the way before, every batch's samples rendered a second time and every "
             "tile's splats folded from full-frame buffers of its own; `image, folded`: the image "
             "without a noise layer the way before. Every repeat checks the images and the noise "
             "layers are the same to the bit.", "",
             "| scene | integrator | spp | image (s) | one pass: cost | re-render: cost | re-render / one pass "
             "| image, folded: cost |", "|---|---|---|---|---|---|---|---|"]
    for name, path, integrator, spp in CASES:
        scene = load_scene(path)
        settings = RenderSettings(width=args.res, height=args.res, spp=spp, seed=1, integrator=integrator,
                                  tile_size=64)
        for way in ways:  # untimed warm-up of every way
            timed(scene, settings.model_copy(update={"spp": 1}), way)
        seconds = {w: [] for w in ways}
        for rep in range(args.reps):
            images = {}
            for way in (ways if rep % 2 == 0 else ways[::-1]):
                s, result = timed(scene, settings, way)
                seconds[way].append(s)
                images[way] = result
            ref = images["image"].rgba
            for way in ways[1:]:
                if not np.array_equal(images[way].rgba, ref):
                    raise SystemExit(f"{name} {integrator}: the {way} image differs from the plain image")
            if not np.array_equal(images["one pass"].variance, images["re-render"].variance):
                raise SystemExit(f"{name} {integrator}: the two ways' variance layers differ")
        cost = {w: summary([s / i for s, i in zip(seconds[w], seconds["image"])]) for w in ways[1:]}
        gain = summary([r / o for r, o in zip(seconds["re-render"], seconds["one pass"])])
        out["cases"][f"{name}/{integrator}"] = {"spp": spp, "seconds": {w: summary(v) for w, v in seconds.items()},
                                                "cost": cost, "rerender_over_one_pass": gain}
        lines.append(f"| {name} | `{integrator}` | {spp} | {fmt(summary(seconds['image']))} "
                     f"| {fmt(cost['one pass'])} | {fmt(cost['re-render'])} | {fmt(gain)} "
                     f"| {fmt(cost['image, folded'])} |")
        print(lines[-1], flush=True)
    write_results("variance-batches", out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
