"""Motion-blur benchmark: what moving instances cost against the same scene standing still.

    .venv/bin/python benchmarks/motion.py [--repeats 3] [--quick]

1. Core: one prototype of ~100k triangles (a wavy 224 x 224 quad grid) placed by 64
   instances, each in a fresh child process built with `_core.Scene`, either static or
   moving through T = 2, 3, 9, 33, 129 time steps (a turn of 30 degrees and a slide over
   the shutter). Per configuration: Scene build time (BVH builds), Embree's own memory,
   and the render time of one tile (path, 96 x 64, 32 spp, 2 threads). Configurations
   are interleaved within each repeat, and each moving figure is reported as the median
   of its per-repeat ratios to the static one (± half-range). The same instances standing
   still over a deforming prototype (its vertices at T = 2, 9, 33 steps) give the cost of
   deformation: build, Embree memory (one vertex buffer per step, a motion-blur BVH) and
   render.
2. Merging under motion: the same rigid scene (static, and moving with T = 2) rendered by
   `vcm` and `sppm` (200,000 light or photon paths, radius 0.05, one iteration's scene pass
   and a 96 x 64 tile at 16 spp), moving with the default 32 time slices and with
   `time_slices` 1 (one grid over the whole shutter, as before slicing): the scene pass
   and the tile pass, each as a median ratio to the static scene per repeat.
3. Translation: a USD stage of 400 Xforms with time-sampled rotation, each holding a
   20 x 20 grid mesh, translated at frame 1 with the camera's shutter (moving instances
   with the steps usd/motion.py chooses) against the same frame with shutter (0, 0) (a
   still frame, flattened as usual): the time per frame, and the ratio.

Results go to docs/benchmarks/motion.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

from common import OUT, summary
from shapes import child_env

STEPS = (2, 3, 9, 33, 129)
DEFORM_STEPS = (2, 9, 33)

_CHILD = r"""
import json, sys, time
import numpy as np
from tessera_renderer import _core

steps, n, mode = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
integrator = sys.argv[4] if len(sys.argv) > 4 else "path"
params = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}

from shapes import wavy_grid

def grid(u=0.0):
    # u in [0, 1]: the wave travels a quarter of its period (a deforming surface).
    return wavy_grid(phase=0.5 * np.pi * u)

def placement(k, side, u):
    # Row-vector matrices (USD's convention): a turn about y by 30 u degrees, a slide by 0.3 u.
    a = np.radians(20.0 * k + 30.0 * u)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros((4, 4), np.float32)
    m[:3, :3] = [[c, 0, -s], [0, 1, 0], [s, 0, c]]
    m[3, :3] = (3.0 * (k % side) + 0.3 * u, 0.0, -3.0 * (k // side))
    m[3, 3] = 1
    return m

pts, tris = grid()
side = int(np.ceil(np.sqrt(n)))
deform = None
if mode == "deform" and steps > 1:  # still instances of one prototype whose vertices move
    pts = grid(u=0.0)[0]
    deform = np.stack([grid(u=j / (steps - 1))[0] for j in range(1, steps)])
extra = {"prototypes": [(pts, tris, np.zeros(len(tris), np.uint32), None, None, deform)],
         "instance_prototype": np.zeros(n, np.uint32),
         "instance_transforms": np.stack([placement(k, side, 0.5) for k in range(n)])}
if steps > 1 and mode == "rigid":
    extra.update(motion_instances=np.arange(n, dtype=np.uint32), motion_time_steps=np.full(n, steps, np.uint32),
                 motion_transforms=np.stack([placement(k, side, j / (steps - 1)) for k in range(n)
                                             for j in range(steps)]))
no_rows = lambda c: np.zeros((0, c), np.float32)
emb0 = _core.embree_memory_bytes()
t = time.perf_counter()
scene = _core.Scene(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.uint32),
                    np.array([[0.6, 0.6, 0.6]], np.float32), np.zeros((1, 3), np.float32), np.zeros(1, bool),
                    no_rows(7), no_rows(6), np.array([[0.3, -1, 0.2, 0, 3, 3, 3]], np.float32), (0.2, 0.2, 0.2),
                    **extra)
build = time.perf_counter() - t
assert scene.has_motion == (steps > 1)
cx, cz = 1.5 * (side - 1), -1.5 * (side - 1)
fwd = np.array([0.0, -0.6, -1.0]); fwd /= np.linalg.norm(fwd)
right = np.array([1.0, 0, 0]); up = np.cross(right, fwd)
cam = _core.Camera(tuple(np.array([cx, 6.0, cz + 9.0])), tuple(right), tuple(up), tuple(fwd), 0.8, 0.8 * 64 / 96, 96, 64)
if integrator != "path":  # a merging integrator: its scene pass, then a tile that merges with it
    t = time.perf_counter()
    product = _core.scene_pass(scene, integrator, 0, 0, 8, 2, params)
    pass_s = time.perf_counter() - t
    t = time.perf_counter()
    splats = np.zeros((64, 96, 3), np.int64)  # vcm's light-tracing strategies splat over the frame
    _core.render_tile(scene, cam, 0, 0, 96, 64, 16, 0, 8, 2, integrator=integrator, integrator_params=params,
                      scene_product=product, splats=splats)
    print(json.dumps({"pass_s": pass_s, "render_s": time.perf_counter() - t, "product_bytes": len(product)}))
    sys.exit(0)
_core.render_tile(scene, cam, 0, 0, 96, 64, 1, 0, 8, 2)  # warm-up
t = time.perf_counter()
_core.render_tile(scene, cam, 0, 0, 96, 64, 32, 0, 8, 2)
print(json.dumps({"steps": steps, "mode": mode, "build_s": build, "embree_bytes": _core.embree_memory_bytes() - emb0,
                  "render_s": time.perf_counter() - t}))
"""


MERGING = {"vcm": {"light_paths": 200000.0, "radius": 0.05},
           "sppm": {"photons": 200000.0, "radius": 0.05}}
# (label, time steps, extra settings): the still scene, the moving one with the default
# slices, and the moving one merged over the whole shutter.
MERGING_ROWS = (("static", 1, {}), ("moving, 32 slices", 2, {}), ("moving, 1 slice", 2, {"time_slices": 1.0}))


def child(steps: int, n: int, mode: str = "rigid", integrator: str = "path", params: dict | None = None) -> dict:
    r = subprocess.run([sys.executable, "-c", _CHILD, str(steps), str(n), mode, integrator, json.dumps(params or {})],
                       capture_output=True, text=True, check=True, env=child_env())
    return json.loads(r.stdout.strip().splitlines()[-1])


def animated_stage(path: str, prims: int = 400) -> None:
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(path)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(24)
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(30, 20, 80))
    cam.CreateShutterOpenAttr(-0.25)
    cam.CreateShutterCloseAttr(0.25)
    q = 20
    pts = [Gf.Vec3f(x / q - 0.5, 0, z / q - 0.5) for z in range(q + 1) for x in range(q + 1)]
    idx = [i for z in range(q) for x in range(q)
           for i in (z * (q + 1) + x, (z + 1) * (q + 1) + x, (z + 1) * (q + 1) + x + 1, z * (q + 1) + x + 1)]
    for k in range(prims):
        xf = UsdGeom.Xform.Define(stage, f"/World/Spin{k}")
        xf.AddTranslateOp().Set(Gf.Vec3d(3.0 * (k % 20), 0, -3.0 * (k // 20)))
        rot = xf.AddRotateYOp()
        for t in range(1, 25):
            rot.Set(15.0 * t + k, t)
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Spin{k}/Grid")
        mesh.CreatePointsAttr(pts)
        mesh.CreateFaceVertexCountsAttr([4] * (q * q))
        mesh.CreateFaceVertexIndicesAttr(idx)
        mesh.CreateSubdivisionSchemeAttr("none")
    stage.GetRootLayer().Save()


def translation_times(path: str, repeats: int) -> dict:
    from tessera_renderer.usd import translate_stage

    moving, still, ratios = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        m = translate_stage(path, 12.0)
        moving.append(time.perf_counter() - t)
        t = time.perf_counter()
        translate_stage(path, 12.0, shutter=(0.0, 0.0))
        still.append(time.perf_counter() - t)
        ratios.append(moving[-1] / still[-1])
    return {"moving_s": summary(moving), "still_s": summary(still), "ratio": summary(ratios),
            "moving_instances": int(len(m.motion_instances)),
            "time_steps": sorted(set(int(s) for s in m.motion_time_steps))}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="8 instances, no files written")
    args = ap.parse_args()
    n = 8 if args.quick else 64
    load_before = os.getloadavg()[0]
    runs: dict[int, list[dict]] = {}
    deforming: dict[int, list[dict]] = {}
    merging: dict[tuple[str, str], list[dict]] = {}
    for _ in range(args.repeats):
        for steps in (1, *STEPS):
            runs.setdefault(steps, []).append(child(steps, n))
        for steps in DEFORM_STEPS:
            deforming.setdefault(steps, []).append(child(steps, n, "deform"))
        for integrator, params in MERGING.items():
            for label, steps, extra in MERGING_ROWS:
                merging.setdefault((integrator, label), []).append(
                    child(steps, n, "rigid", integrator, {**params, **extra}))
    result: dict = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                "load_average_before": load_before}, "instances": n, "core": {}}
    for steps in (1, *STEPS):
        rs = runs[steps]
        row = {f: summary([r[f] for r in rs]) for f in ("build_s", "embree_bytes", "render_s")}
        if steps > 1:
            for f in ("build_s", "render_s"):
                row[f + "_ratio"] = summary([r[f] / s[f] for r, s in zip(rs, runs[1])])
        result["core"][steps] = row
    result["deforming"] = {}
    for steps, rs in deforming.items():
        row = {f: summary([r[f] for r in rs]) for f in ("build_s", "embree_bytes", "render_s")}
        for f in ("build_s", "render_s", "embree_bytes"):
            row[f + "_ratio"] = summary([r[f] / s[f] for r, s in zip(rs, runs[1])])
        result["deforming"][steps] = row
    result["merging"] = {}
    for integrator in MERGING:
        still = merging[(integrator, "static")]
        for label, _, _ in MERGING_ROWS:
            rs = merging[(integrator, label)]
            row = {f: summary([r[f] for r in rs]) for f in ("pass_s", "render_s", "product_bytes")}
            for f in ("pass_s", "render_s"):
                row[f + "_ratio"] = summary([r[f] / s[f] for r, s in zip(rs, still)])
            result["merging"][f"{integrator}: {label}"] = row
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "spinning.usda")
        animated_stage(path, 40 if args.quick else 400)
        result["translation"] = translation_times(path, args.repeats)
    result["machine"]["load_average_after"] = os.getloadavg()[0]
    md = render_md(result)
    print(md)
    if not args.quick:
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / "motion.json").write_text(json.dumps(result, indent=1))
        (OUT / "motion.md").write_text(md)
    return 0


def render_md(r: dict) -> str:
    m = r["machine"]
    lines = ["# Motion-blur benchmark", "",
             f"Measured by `benchmarks/motion.py` on {m['platform']} ({m['cpus']} CPUs, shared; 1-minute load "
             f"average {m['load_average_before']:.1f} before, {m['load_average_after']:.1f} after). "
             f"{r['instances']} instances of a 100,352-triangle prototype; each row a fresh process, rows "
             "interleaved within each repeat; medians ± half-range, ratios taken per repeat against the "
             "static row. Render: path, 96 x 64, 32 spp, 2 threads.", "",
             "| time steps | build | build / static | Embree memory | render | render / static |",
             "|---|---|---|---|---|---|"]
    for steps, row in r["core"].items():
        label = "static" if int(steps) == 1 else str(steps)
        ratio = lambda f: (f"{row[f]['median']:.2f} ± {row[f]['half_range']:.2f}" if f in row else "1")
        lines.append(f"| {label} | {row['build_s']['median'] * 1e3:.1f} ms ± {row['build_s']['half_range'] * 1e3:.1f} "
                     f"| {ratio('build_s_ratio')} | {row['embree_bytes']['median'] / 1e6:.1f} MB "
                     f"| {row['render_s']['median']:.3f} s ± {row['render_s']['half_range']:.3f} "
                     f"| {ratio('render_s_ratio')} |")
    lines += ["", "## Deforming meshes", "",
              "The same 64 still instances of one prototype whose vertices move (a wave travelling a quarter "
              "period over the shutter: one Embree vertex buffer per time step), against the static row "
              "above, per repeat.", "",
              "| time steps | build / static | Embree memory | memory / static | render / static |",
              "|---|---|---|---|---|"]
    for steps, row in r.get("deforming", {}).items():
        ratio = lambda f: f"{row[f]['median']:.2f} ± {row[f]['half_range']:.2f}"
        lines.append(f"| {steps} | {ratio('build_s_ratio')} | {row['embree_bytes']['median'] / 1e6:.1f} MB "
                     f"| {ratio('embree_bytes_ratio')} | {ratio('render_s_ratio')} |")
    if r.get("merging"):
        lines += ["", "## Merging under motion", "",
                  "vcm and sppm on the same instances (200,000 light or photon paths, radius 0.05): one "
                  "iteration's scene pass and a 96 x 64 tile at 16 spp, each a fresh process, ratios per repeat "
                  "against the static scene. With motion the passes' paths live in time slices and the grids "
                  "key cells by slice, so a camera vertex visits only its slice's points; `time_slices` 1 merges "
                  "over the whole shutter (and is biased on moving receivers, docs/motion.md).", "",
                  "| integrator: scene | scene pass | pass / static | tile | tile / static | product |",
                  "|---|---|---|---|---|---|"]
        for label, row in r["merging"].items():
            ratio = lambda f: f"{row[f]['median']:.2f} ± {row[f]['half_range']:.2f}"
            lines.append(f"| {label} | {row['pass_s']['median']:.3f} s | {ratio('pass_s_ratio')} "
                         f"| {row['render_s']['median']:.3f} s | {ratio('render_s_ratio')} "
                         f"| {row['product_bytes']['median'] / 1e6:.1f} MB |")
    t = r["translation"]
    lines += ["", "## Translation per frame", "",
              f"A stage of {t['moving_instances']} spinning Xforms (each a 20 x 20 grid, rotateY keyed every "
              f"frame), translated at frame 12: with the camera's shutter (-0.25, 0.25) they become moving "
              f"instances with {', '.join(map(str, t['time_steps']))} steps; with shutter (0, 0) the frame is "
              "still and flattened.", "",
              f"- with motion: {t['moving_s']['median']:.2f} s ± {t['moving_s']['half_range']:.2f}",
              f"- still: {t['still_s']['median']:.2f} s ± {t['still_s']['half_range']:.2f}",
              f"- ratio: {t['ratio']['median']:.2f} ± {t['ratio']['half_range']:.2f} (n={t['ratio']['n']})", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
