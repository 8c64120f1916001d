"""Radiosity: solve time, memory and size on the Cornell box and on a scene of 195k
triangles, the stochastic solver's accuracy there against path tracing, and the
preview's frame rate.

    .venv/bin/python benchmarks/radiosity.py [--sizes 100,70,55.5] [--large 0:16,25:16,25:64,25:256] [--frames 100] [--threads 2]

Per element size, in a fresh child process (so that its peak resident memory is the
solve's): meshing + the progressive, hierarchical and stochastic solves of
examples/cornell/cornell.usda (Scene.scene_pass("radiosity")), its elements, display
vertices, shots (links, iterations) and final residual (from the product's header), wall
time, and the process's peak RSS above the loaded scene's.

The large scene is the Cornell box with the usd-wg Fancy Teapot (../shared/scenes,
CC0; Catmull-Clark, 6120 faces refined to 195k triangles) on its floor, both made
Lambertian (material_params dropped, as in tests/renderer/test_radiosity.py, so that
radiosity's model is exact). The stochastic solver solves it at each `--large`
element size (0: the default, a tenth of the scene's diameter) and rays per element;
each solution's image (128 x 128, 4 spp) is compared with
a `path` render at 1024 spp, per region (walls, floor, teapot) and by relMSE over the
frame. The progressive solver is not run there: its 3.8e10 element pairs would take
hours (the Cornell rows give its pairs per second).

Then the preview (tessera/preview.py) renders `--frames` 256 x 256 frames along
an orbit on `--threads` threads: frames per second by wall clock, and by the process's CPU
time divided by the threads (what an otherwise idle machine of that many cores would
give; the load average is recorded, since helpers share the machine). Writes
docs/benchmarks/radiosity.{md,json}, keeping the markdown's hybrid section (measured by
`tessera bench`, see there).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import CORNELL, OUT, REPO, rel_mse

NOTE = ("For the hierarchical solver, \"residual\" is the last Jacobi change relative to the power; at its "
        "default oracle tolerance 1e-5 it agrees with the progressive solver within 1 % per wall region "
        "(tests/renderer/test_radiosity.py; docs/integrators.md, \"Hierarchical solver\"). The issue's target of 25 frames/s at 256 x 256 on 2 threads "
        "was met (152 frames/s by wall clock with the machine idle, load 0.4; 17 frames/s while seven helpers shared "
        "its 2 cores, load 14). The stochastic solver's rays cost O(rays), not O(element pairs): it is the default "
        "above 4096 elements and in scenes with mirrors or glass, whose light only it carries.")

CHILD = r"""
import dataclasses, json, struct, sys, time
from tessera_renderer import Scene, load_scene
loaded = load_scene(sys.argv[1])
scene = Scene(dataclasses.replace(loaded.data, material_params=None)) if sys.argv[7] == "1" else loaded
def rss_kb(field):
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith(field + ":"))
open("/proc/self/clear_refs", "w").write("5")  # resets the peak (VmHWM) to the current RSS
before = rss_kb("VmRSS")
params = {"solver": float(sys.argv[4]), "tolerance": float(sys.argv[5]), "rays_per_element": float(sys.argv[6])}
if float(sys.argv[2]) > 0:
    params["element_size"] = float(sys.argv[2])
t = time.perf_counter()
product = scene.scene_pass("radiosity", 0, threads=int(sys.argv[3]), integrator_params=params)
seconds = time.perf_counter() - t
after = rss_kb("VmHWM")
if sys.argv[8]:
    open(sys.argv[8], "wb").write(product)
_, elements, vertices, shots, residual, converged = struct.unpack("4sIIIfI", product[8:32])  # after the slice count
print(json.dumps(dict(element_size=float(sys.argv[2]), solver=("progressive", "hierarchical", "stochastic")[int(sys.argv[4])],
                      tolerance=float(sys.argv[5]), rays_per_element=float(sys.argv[6]), triangles=scene.num_triangles,
                      elements=elements, vertices=vertices, shots=shots, residual=residual, converged=bool(converged),
                      seconds=seconds, peak_rss_mb=(after - before) / 1024, product_bytes=len(product))))
"""
# Solvers by their `solver` setting, and their default tolerances.
PROGRESSIVE, HIERARCHICAL, STOCHASTIC = 0, 1, 2
TOLERANCE = {PROGRESSIVE: 1e-3, HIERARCHICAL: 1e-5, STOCHASTIC: 1e-3}
LUM = np.array([0.2126, 0.7152, 0.0722])
TEAPOT = REPO.parent / "shared" / "scenes" / "usdwg_teapot" / "geo" / "FancyTeapot.usd"
# Pixel rows and columns (128 x 128) of the large scene's regions, clear of edges and blocks.
REGIONS = {"back": (16, 36, 44, 84), "left": (32, 80, 4, 18), "right": (32, 80, 110, 124),
           "ceiling": (6, 16, 16, 44), "floor": (112, 124, 90, 120), "teapot": (88, 104, 28, 46)}


def solve(scene: Path, size: float, threads: int, solver: int = PROGRESSIVE, rays: float = 1024,
          lambertian: bool = False, keep: Path | None = None) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(scene), str(size), str(threads), str(solver),
                          str(TOLERANCE[solver]), str(rays), "1" if lambertian else "0", str(keep or "")],
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def large_scene(folder: Path) -> Path:
    """The Cornell box with the Fancy Teapot on its floor, written into `folder`."""
    from pxr import Gf, Usd, UsdGeom
    shutil.copy(CORNELL, folder / "cornell.usda")
    shutil.copy(TEAPOT, folder / "FancyTeapot.usd")
    stage = Usd.Stage.CreateNew(str(folder / "room.usda"))
    stage.GetRootLayer().subLayerPaths.append("cornell.usda")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    teapot = UsdGeom.Xform.Define(stage, "/Teapot")
    teapot.GetPrim().GetReferences().AddReference("FancyTeapot.usd", "/FancyTeapot")
    teapot.AddTranslateOp().Set(Gf.Vec3d(400, 0, 110))
    teapot.AddScaleOp().Set(Gf.Vec3d(500, 500, 500))
    stage.GetRootLayer().Save()
    return folder / "room.usda"


def large_scene_accuracy(path: Path, runs: list[tuple[float, float]], threads: int) -> dict:
    """Stochastic solutions of the large scene against path at 1024 spp."""
    from tessera_renderer import Scene, load_scene
    scene = Scene(dataclasses.replace(load_scene(str(path)).data, material_params=None))
    w = 128
    t = time.perf_counter()
    reference = scene.render_tile(0, 0, w, w, width=w, height=w, spp=1024, threads=threads, integrator="path", seed=1)
    path_seconds = time.perf_counter() - t

    def regions(img):
        return {k: float((img[r0:r1, c0:c1, :3] @ LUM).mean()) for k, (r0, r1, c0, c1) in REGIONS.items()}

    ref = regions(reference)
    rows = []
    for size, r in runs:
        keep = path.parent / f"solution-{size:g}-{r:g}.bin"
        row = solve(path, size, threads, STOCHASTIC, r, lambertian=True, keep=keep)
        params = {"solver": STOCHASTIC, "rays_per_element": r, **({"element_size": size} if size > 0 else {})}
        img = scene.render_tile(0, 0, w, w, width=w, height=w, spp=4, threads=threads, integrator="radiosity",
                                integrator_params=params, scene_product=keep.read_bytes(), seed=2)
        got = regions(img)
        row["region_errors"] = {k: got[k] / ref[k] - 1 for k in ref}
        row["rel_mse"] = float(rel_mse(img[..., :3], reference[..., :3]))
        rows.append(row)
        print(row, flush=True)
    return {"path_seconds_1024spp": path_seconds, "solves": rows}


def preview_rate(frames: int, threads: int) -> dict:
    from tessera.preview import RadiosityPreview
    from tessera_renderer import load_scene
    preview = RadiosityPreview(load_scene(str(CORNELL)), width=256, height=256, threads=threads)
    preview.frame()
    cpu0, load0 = time.process_time(), os.getloadavg()[0]
    b = preview.benchmark(frames)
    cpu = time.process_time() - cpu0
    b.update(cpu_seconds=cpu, fps_cpu=frames * threads / cpu, load_average=load0, threads=threads)
    return b


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="100,70,55.5")
    ap.add_argument("--large", default="0:16,25:16,25:64,25:256")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    solves = []
    for size in (float(s) for s in args.sizes.split(",")):
        for solver in (PROGRESSIVE, HIERARCHICAL, STOCHASTIC):
            solves.append(solve(CORNELL, size, args.threads, solver))
            print(solves[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        runs = [tuple(float(v) for v in run.split(":")) for run in args.large.split(",")]
        large = large_scene_accuracy(large_scene(Path(tmp)), runs, args.threads)
    rate = preview_rate(args.frames, args.threads)
    print(rate)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "radiosity.json").write_text(json.dumps({"solves": solves, "large_scene": large, "preview": rate},
                                                   indent=2) + "\n")
    lines = ["# Radiosity: solve and preview (benchmarks/radiosity.py)", "",
             f"Cornell box (examples/cornell/cornell.usda, 32 triangles), {args.threads} threads, "
             f"load average {rate['load_average']:.1f} when the preview ran (the machine is shared). "
             "Shots: progressive shots, hierarchical links, stochastic iterations (1024 rays per element first, then "
             "in proportion to the unshot power).", "",
             "| solver | element size | elements | vertices | element pairs | shots / links / iterations | residual | solve s | peak RSS MB | product KB |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in solves:
        lines.append(f"| {s['solver']} (tolerance {s['tolerance']:g}) | {s['element_size']:g} | {s['elements']} | "
                     f"{s['vertices']} | {s['elements'] ** 2} | {s['shots']} | "
                     f"{s['residual']:.1e} | {s['seconds']:.2f} | {s['peak_rss_mb']:.1f} | {s['product_bytes'] / 1024:.0f} |")
    first = large["solves"][0]
    lines += ["", f"## A scene of {first['triangles'] / 1000:.0f}k triangles (stochastic solver)", "",
              f"The Cornell box with the usd-wg Fancy Teapot (CC0) on its floor, {first['triangles']} triangles, "
              "made Lambertian; " f"{args.threads} threads. "
              "Each solution's image (128 x 128, 4 spp) against `path` at 1024 spp "
              f"({large['path_seconds_1024spp']:.1f} s): the mean of each region relative to path's, and relMSE "
              "over the frame. The progressive solver would need the element pairs' form factors, "
              f"{first['elements'] ** 2:.1e} of them at the default size. The meshing bias is the walls' and the "
              "floor's (the teapot's own triangles are single elements): it shrinks from the default element size "
              "(a tenth of the diameter) to 25 units; the rays' noise is small beside it.", "",
              "| element size | elements | rays per element (first shot) | iterations | solve s | peak RSS MB | product MB | "
              + " | ".join(REGIONS) + " | relMSE |",
              "|---|---|---|---|---|---|---|" + "---|" * len(REGIONS) + "---|"]
    for s in large["solves"]:
        lines.append(f"| {s['element_size'] or 'default'} | {s['elements']} | {s['rays_per_element']:g} | {s['shots']} | {s['seconds']:.2f} | {s['peak_rss_mb']:.0f} | "
                     f"{s['product_bytes'] / 2 ** 20:.1f} | "
                     + " | ".join(f"{100 * s['region_errors'][k]:+.1f} %" for k in REGIONS)
                     + f" | {s['rel_mse']:.2e} |")
    lines += ["", f"Preview (default element size, 256 x 256, 1 sample per pixel, {args.threads} threads, "
              f"{rate['frames']} frames along an orbit): {rate['fps']:.1f} frames/s by wall clock, "
              f"{rate['fps_cpu']:.1f} frames/s by CPU time per thread.", "", NOTE, ""]
    md = OUT / "radiosity.md"
    kept = md.read_text().split("## Hybrid against path", 1) if md.exists() else []
    (md).write_text("\n".join(lines) + ("\n## Hybrid against path" + kept[1] if len(kept) == 2 else ""))


if __name__ == "__main__":
    main()
