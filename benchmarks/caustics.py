"""Photon mapping's home ground: time to relMSE 1e-2 and 1e-3 on the glass-ball caustic and
on the same caustic seen only in a mirror (L S D S E), for `path`, `bdpt`, `photon`,
`sppm` and `vcm`, with Mitsuba 3 (llvm_ad_rgb, path) side by side in the same run.

    .venv/bin/python benchmarks/caustics.py [--res 64] [--reps 2]

It is `tessera bench` (tessera/tessera_tools/bench.py: interleaved repetitions, cached
references whose own error is subtracted, the peer's agreement checked before any ratio)
with ladders long enough to reach relMSE 1e-3, written to docs/benchmarks/caustics/. Two
repetitions take about 35 minutes plus 10 for the references. Then the scene passes' products
(photon maps, light-vertex grids): bytes and seconds per iteration, to products.json.
`--products` measures only those.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from common import OUT, REPO

SCENES = {"caustic": REPO / "examples" / "caustic" / "caustic.usda",
          "caustic-mirror": REPO / "examples" / "caustic" / "caustic_mirror.usda"}


def products() -> list[dict]:
    """Each merging integrator's scene pass, default settings, 2 threads: its product's size
    and its seconds (trace and grid build together), at iterations 0, 3 and 6 (passes of 1,
    4 and 32 times the first pass's samples: sppm and vcm trace that many batches)."""
    from tessera_renderer import load_scene

    rows = []
    for name, path in SCENES.items():
        scene = load_scene(path)
        for integrator in ("photon", "sppm", "vcm"):
            for iteration in (0, 3, 6):
                start = time.perf_counter()
                product = scene.scene_pass(integrator, iteration, seed=1, max_depth=64, threads=2)
                rows.append({"scene": name, "integrator": integrator, "iteration": iteration,
                             "megabytes": len(product) / 1e6, "seconds": time.perf_counter() - start})
                print(f"  {name} {integrator} iteration {iteration}: {rows[-1]['megabytes']:.2f} MB in "
                      f"{rows[-1]['seconds']:.2f} s", file=sys.stderr, flush=True)
    return rows


def main() -> int:
    from tessera_tools import bench

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--products", action="store_true", help="only the scene passes' products")
    args = ap.parse_args()
    if args.products:
        (OUT / "caustics").mkdir(parents=True, exist_ok=True)
        (OUT / "caustics" / "products.json").write_text(json.dumps(products(), indent=2) + "\n")
        return 0
    cfg = bench.Config(res=args.res, reps=args.reps, budget=2.0)
    # References with about a quarter of relMSE 1e-3 of their own (bdpt 2 x 8192 spp on the
    # caustic, path 2 x 65536 on the mirror scene), subtracted from every point.
    cfg.ref_spp.update({"bdpt": 4096, "path": 8192})
    # Ladders that reach relMSE 1e-3 for bdpt, vcm and sppm (measured, not extrapolated).
    # path and Mitsuba stop at 16384 spp (~2.5e-3, 60 s a render at 64 px): their slope is
    # Monte Carlo's -1 and reaching 1e-3 would cost ~4 minutes a render.
    cfg.ladders.update({"path": (4, 16, 64, 256, 1024, 4096, 16384), "mitsuba": (4, 16, 64, 256, 1024, 4096, 16384),
                        "bdpt": (1, 4, 16, 64, 256, 1024, 4096, 16384), "vcm": (1, 4, 16, 64, 256, 1024),
                        "sppm": (4, 16, 64, 256, 512), "photon": (1, 4, 16)})
    cfg.scene_ladders = {"caustic": {"vcm": (1, 4, 16, 64, 256, 1024, 2048)},
                         # bdpt reaches L S D S E only by path tracing (its s = 0 strategy): ~1e4 s to 1e-3.
                         "caustic-mirror": {"bdpt": (1, 4, 16, 64, 256)}}
    result = bench.run(list(SCENES), ["path", "bdpt", "photon", "sppm", "vcm"], cfg,
                       OUT / "caustics", ("llvm_ad_rgb",), log=lambda m: print(m, file=sys.stderr, flush=True))
    (OUT / "caustics" / "products.json").write_text(json.dumps(products(), indent=2) + "\n")
    return 0 if result["scenes"] else 1


if __name__ == "__main__":
    sys.exit(main())
