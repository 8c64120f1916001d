"""Farm efficiency of photon passes: `sppm` and `vcm` on the glass-ball caustic, rendered
locally (2 threads) and on the farm (two 1-thread workers), interleaved.

    .venv/bin/python benchmarks/farm_photons.py [--repeats 3]

Each iteration of a merging integrator is a scene task (photons or light paths, one
worker) and then its tiles (both workers), in lockstep: while one worker traces the
iteration's photons the other waits, so the farm's efficiency (local seconds / farm
seconds, upload to EXR downloaded) is bounded by (S2 + T2) / (S1 + T2), S_k the scene
passes' seconds on k threads and T2 the tiles' on two. The scene passes are timed apart
(every iteration's, 1 and 2 threads) so that the bound is printed beside the measurement.
Every farm image is compared with the local one: they must be the same bits.
Results go to docs/benchmarks/farm-photons.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from contextlib import ExitStack

import numpy as np
from common import OUT, REPO, fmt, summary
from farm import Farm

CAUSTIC = REPO / "examples" / "caustic" / "caustic.usda"
FORM = dict(width=256, height=256, tile_size=64, seed=3, max_depth=8, target_error=1e-9, min_spp=1, max_spp=16)


def settings(integrator: str):
    from tessera_base.protocol import RenderSettings

    return RenderSettings(**FORM, integrator=integrator)


def scene_pass_seconds(scene, integrator: str, threads: int) -> float:
    from tessera_base.film import run_scene_pass
    from tessera_base.protocol import pass_range

    st, total, k = settings(integrator), 0.0, 0
    while pass_range(st, k) is not None:
        start = time.perf_counter()
        run_scene_pass(scene, st, k, integrator=integrator, threads=threads)
        total += time.perf_counter() - start
        k += 1
    return total


def farm_rgb(farm: Farm, job_id: str) -> np.ndarray:
    import OpenImageIO as oiio

    data = farm.client.get(f"/jobs/{job_id}/image.exr")
    data.raise_for_status()
    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(data.content)
        f.flush()
        return oiio.ImageBuf(f.name).get_pixels(oiio.FLOAT)[..., :3]


def measure(integrator: str, repeats: int) -> dict:
    from tessera_renderer import load_scene

    from tessera.local import render_image

    scene = load_scene(str(CAUSTIC))
    local, farm_t, ratio, same = [], [], [], []
    s1 = [scene_pass_seconds(scene, integrator, 1) for _ in range(repeats)]
    s2 = [scene_pass_seconds(scene, integrator, 2) for _ in range(repeats)]
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        farm = Farm(stack, tmp, workers=2)
        farm.render(scene=CAUSTIC, width=16, height=16, spp=1, integrator=integrator)  # warm-up
        for i in range(repeats):
            # Without the variance layers: the farm computes them only when a job asks
            # (aovs=variance), and for splatting integrators they cost locally 2-3x the render.
            result = render_image(scene, settings(integrator), threads=2, progress=False, variance=False)
            start = time.perf_counter()
            job_id = farm.submit(scene=CAUSTIC, **FORM, integrator=integrator)
            farm.wait(job_id)
            rgb = farm_rgb(farm, job_id)
            f = time.perf_counter() - start
            local.append(result.seconds)
            farm_t.append(f)
            ratio.append(result.seconds / f)
            same.append(bool(np.array_equal(rgb, result.rgba[..., :3])))
            print(f"  {integrator} repeat {i + 1}: local {result.seconds:.2f} s, farm {f:.2f} s, "
                  f"ratio {result.seconds / f:.3f}, same bits {same[-1]}", flush=True)
    tiles = [l - s for l, s in zip(local, s2)]
    bound = [(a + t) / (b + t) for a, b, t in zip(s2, s1, tiles)]
    return {"local_seconds": summary(local), "farm_seconds": summary(farm_t), "efficiency": summary(ratio),
            "scene_pass_seconds_1_thread": summary(s1), "scene_pass_seconds_2_threads": summary(s2),
            "bound": summary(bound), "same_bits": all(same)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    load = os.getloadavg()[0]
    rows = {}
    for integrator in ("sppm", "vcm"):
        print(f"{integrator} ...", flush=True)
        rows[integrator] = measure(integrator, args.repeats)
    result = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "cpus": os.cpu_count(),
              "load_at_start": load, "form": FORM, "scene": str(CAUSTIC.relative_to(REPO)), "integrators": rows}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "farm-photons.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = ["# Farm efficiency of photon passes", "",
             f"Written by `benchmarks/farm_photons.py` on {result['date']}; {result['cpus']} CPUs, load average "
             f"{load:.2f} at start. `examples/caustic/caustic.usda` at {FORM['width']}x{FORM['height']}, tiles of "
             f"{FORM['tile_size']}, passes of 1, 1, 2, 4, 8 samples (5 iterations, each a scene task and its "
             f"{(FORM['width'] // FORM['tile_size']) ** 2} tiles), default integrator settings. Local: 2 threads in "
             "this process, without the variance layers (the farm makes them only when a job asks for "
             "them); farm: a private Redis, the API and two 1-thread workers, upload to EXR downloaded. "
             f"Medians ± half-range over {args.repeats} repeats, local and farm interleaved; ratios per repeat pair.",
             "", "| integrator | local | farm | **efficiency** (local / farm) | bound (S2 + T2) / (S1 + T2) "
             "| scene passes, 1 thread / 2 threads | farm image = local, bit for bit |", "|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {fmt(r['local_seconds'], ' s')} | {fmt(r['farm_seconds'], ' s')} | "
                     f"**{fmt(r['efficiency'])}** | {fmt(r['bound'])} | "
                     f"{r['scene_pass_seconds_1_thread']['median']:.2f} s / "
                     f"{r['scene_pass_seconds_2_threads']['median']:.2f} s | {'yes' if r['same_bits'] else 'NO'} |")
    lines += ["", "While one worker runs an iteration's scene task the other has nothing to do (the tiles "
              "need its product), so a scene pass costs the farm its 1-thread time; locally it runs on both "
              "threads. The bound is what the farm would reach with no dispatch overhead at all."]
    (OUT / "farm-photons.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if all(r["same_bits"] for r in rows.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
