"""What the full renderer's generality costs a Lambert-only scene: the full build against a
build that can render nothing but Lambertian triangles under triangle lights.

    .venv/bin/python benchmarks/lambert_only.py [--res 256] [--reps 9]

Issue 13's target: a Lambert-only scene renders at least 95 % as fast with the full feature
set compiled in as with a build that has only Lambert. Both sides are the renderer core at
this tree, built Release with the same flags into build/bench-lambert/ (`_core` only); the
baseline adds -DTESSERA_LAMBERT_ONLY=ON (renderer/core/feature_set.h), which compiles out
every test the full build makes for textures, normal maps, cutouts, instances, motion,
curves, sphere and shaped lights, the lens and AOVs, and leaves BSDF a DiffuseBSDF only.

Scene: `tessera bench`'s cornell-lambert (the Cornell box, every opaque UsdPreviewSurface
made Lambertian), without its texture coordinates (the baseline has no textures to read
them; the image does not depend on them). Cases: `path` and `bdpt`. Each side runs in one
warm child process (scene loaded and a warm-up tile rendered before any timing); the sides
alternate within each repeat (A B, then B A) after an untimed render of every case on
each side, and every measurement checks that the two images are the same to the bit. Speed = baseline time / full time per repeat (1 = as fast),
median ± half-range over repeats. Writes docs/benchmarks/lambert-only.{md,json}.
"""
from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys

from common import LOAD_CORE, REPO, WarmChild, fmt, summary, write_results

WORK = REPO / "build" / "bench-lambert"
TARGET = 0.95
CASES = {"path": 64, "bdpt": 16}  # integrator: spp at 256 x 256 (a few seconds each)

CHILD = LOAD_CORE + r"""
import hashlib, json, time
from dataclasses import replace
import numpy as np
from tessera_renderer import Scene
from tessera_tools.bench import SCENES, bench_scene_data
scene = Scene(replace(bench_scene_data(SCENES["cornell-lambert"]), uvs=None))
scene.render_tile(0, 0, 8, 8, width=8, height=8, spp=1, seed=0, threads=2, integrator="path")
for line in sys.stdin:
    integ, spp, res = line.split()
    spp, res = int(spp), int(res)
    splats = np.zeros((res, res, 3), np.int64) if integ in ("bdpt", "light") else None
    t = time.perf_counter()
    out = scene.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=7, threads=2, integrator=integ,
                            splats=splats)
    seconds = time.perf_counter() - t
    rgba = np.ascontiguousarray(out[0] if isinstance(out, tuple) else out, np.float32)
    digest = hashlib.sha256(rgba.tobytes() + (splats.tobytes() if splats is not None else b"")).hexdigest()
    print(json.dumps({"seconds": seconds, "image": digest}), flush=True)
"""


def build(name: str, lambert_only: bool) -> str:
    """Configures and builds `_core` of this tree into build/bench-lambert/<name>."""
    out = WORK / name
    subprocess.run(["cmake", "-S", str(REPO), "-B", str(out), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
                    "-DTESSERA_BUILD_TESTS=OFF", "-DSKBUILD=ON", f"-DPython_EXECUTABLE={sys.executable}",
                    f"-DTESSERA_LAMBERT_ONLY={'ON' if lambert_only else 'OFF'}"],
                   check=True, stdout=subprocess.DEVNULL)
    subprocess.run(["cmake", "--build", str(out), "--target", "_core", "-j", str(os.cpu_count() or 2)],
                   check=True, stdout=subprocess.DEVNULL)
    (core,) = (out / "renderer").glob("_core*.so")
    return str(core)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--reps", type=int, default=9)
    args = ap.parse_args()
    head = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], check=True,
                          capture_output=True, text=True).stdout.strip()
    print(f"building _core at {head} twice (full, lambert-only) into {WORK}", flush=True)
    sides = {"full": WarmChild(CHILD, build("full", False)), "lambert-only": WarmChild(CHILD, build("only", True))}
    for side in sides.values():  # an untimed render of each case: the first one of a process runs slow
        for integ, spp in CASES.items():
            side.ask(integ, spp, args.res)
    load_before = os.getloadavg()[0]
    times = {c: {s: [] for s in sides} for c in CASES}
    speed = {c: [] for c in CASES}
    for r in range(args.reps):
        order = list(sides) if r % 2 == 0 else list(sides)[::-1]
        for integ, spp in CASES.items():
            got = {s: sides[s].ask(integ, spp, args.res) for s in order}
            if got["full"]["image"] != got["lambert-only"]["image"]:
                sys.exit(f"{integ}: the two builds' images differ")
            for s in sides:
                times[integ][s].append(got[s]["seconds"])
            speed[integ].append(got["lambert-only"]["seconds"] / got["full"]["seconds"])
            print(f"repeat {r + 1} {integ}: full {got['full']['seconds']:.3f} s, lambert-only "
                  f"{got['lambert-only']['seconds']:.3f} s, speed {speed[integ][-1]:.3f}", flush=True)
    for s in sides.values():
        s.close()
    result = {"revision": head, "res": args.res, "reps": args.reps, "target": TARGET, "load": load_before,
              "machine": f"{platform.platform()} ({os.cpu_count()} CPUs)",
              "cases": {c: {"spp": CASES[c], "full": summary(times[c]["full"]),
                            "lambert_only": summary(times[c]["lambert-only"]), "speed": summary(speed[c])}
                        for c in CASES}}
    lines = ["# A Lambert-only scene: full build against a Lambert-only build", "",
             f"Written by `benchmarks/lambert_only.py` at {head}: cornell-lambert (no texture coordinates), "
             f"{args.res}x{args.res}, 2 threads, {args.reps} interleaved repetitions in two warm processes, "
             f"median ± half-range. Both builds are this tree's core, Release, same flags; the baseline adds "
             f"-DTESSERA_LAMBERT_ONLY=ON (renderer/core/feature_set.h). Every pair of images is identical to the "
             f"bit. Speed = Lambert-only time / full time per repetition (1: the full build is as fast); "
             f"issue 13's target is at least {TARGET:.2f}.", "",
             "| integrator | spp | full build s | Lambert-only build s | speed of the full build | target met |",
             "|---|---|---|---|---|---|"]
    for c, v in result["cases"].items():
        met = "yes" if v["speed"]["median"] >= TARGET else "no"
        lines.append(f"| {c} | {v['spp']} | {fmt(v['full'])} | {fmt(v['lambert_only'])} | {fmt(v['speed'])} | {met} |")
    lines += ["", f"Load average at the start: {load_before:.2f} ({os.cpu_count()} shared vCPUs)."]
    write_results("lambert-only", result, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
