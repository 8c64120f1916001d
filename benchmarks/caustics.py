"""Photon mapping's home ground: time to relMSE 1e-2 and 1e-3 on the glass-ball caustic and
on the same caustic seen only in a mirror (L S D S E), for `path`, `bdpt`, `photon`,
`sppm` and `vcm`, with Mitsuba 3 (llvm_ad_rgb, path) side by side in the same run.

    .venv/bin/python benchmarks/caustics.py [--res 64] [--reps 3]

It is `tessera bench` (tessera/tessera_tools/bench.py: interleaved repetitions, cached
references, the peer's agreement checked before any ratio) with ladders long enough to
reach relMSE 1e-3, written to docs/benchmarks/caustics/. Then the scene passes' products
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
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--products", action="store_true", help="only the scene passes' products")
    args = ap.parse_args()
    if args.products:
        (OUT / "caustics").mkdir(parents=True, exist_ok=True)
        (OUT / "caustics" / "products.json").write_text(json.dumps(products(), indent=2) + "\n")
        return 0
    cfg = bench.Config(res=args.res, reps=args.reps, budget=2.0)
    cfg.ladders.update({"path": (4, 16, 64, 256, 1024), "mitsuba": (4, 16, 64, 256, 1024),
                        "bdpt": (1, 4, 16, 64, 256), "vcm": (1, 4, 16, 64, 256),
                        "sppm": (4, 16, 64, 256), "photon": (1, 4, 16)})
    result = bench.run(list(SCENES), ["path", "bdpt", "photon", "sppm", "vcm"], cfg,
                       OUT / "caustics", ("llvm_ad_rgb",), log=lambda m: print(m, file=sys.stderr, flush=True))
    (OUT / "caustics" / "products.json").write_text(json.dumps(products(), indent=2) + "\n")
    return 0 if result["scenes"] else 1


if __name__ == "__main__":
    sys.exit(main())
