"""Radiosity's default (no setting chosen) on lit planes and the Cornell box: its error and
its cost, for this build and, with --baseline, another build's `_core*.so` side by side.

    .venv/bin/python benchmarks/radiosity_default.py [--baseline /path/to/_core.so] [--reps 3]

Lit planes (issue 46): a 4 x 4 Lambertian floor (albedo 0.5) under a 1 x 1 RectLight, an
emissive hexagon mesh (radius 0.6) or a SphereLight (radius 0.2), 1 unit above its centre;
the radiosity read at 6 points (centre, off axis, near an edge, near a corner) against the
closed form (Lambert's polygon factor; pi L R^2 cos / D^2), as in
tests/renderer/test_radiosity.py. Cornell box (examples/cornell, made Lambertian as in that
test): each wall region's mean (64 x 64, 4 spp) against `path` at 1024 spp. For each: the
elements of the final mesh (the product's header) and the solve's wall time on 2 threads
(median of --reps, each in a fresh process). Writes docs/benchmarks/radiosity-default.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import CORNELL, LOAD_CORE, REPO, write_results

CHILD = LOAD_CORE + r"""
import dataclasses, json, math, struct, time
import numpy as np
from tessera_renderer import Scene, load_scene, _core
kind, path = sys.argv[2], sys.argv[3]
loaded = load_scene(path)
scene = Scene(dataclasses.replace(loaded.data, material_params=None)) if kind == "cornell" else loaded
t = time.perf_counter()
product = scene.scene_pass("radiosity", 0, threads=2, integrator_params={})
solve = time.perf_counter() - t
elements = struct.unpack("4sII", product[8:20])[1]
out = {"solve_s": solve, "elements": elements}
if kind == "cornell":
    img = scene.render_tile(0, 0, 64, 64, width=64, height=64, spp=4, threads=2, integrator="radiosity",
                            scene_product=product, seed=2)
    np.save(sys.argv[4], img)
else:
    offset = np.asarray(scene.data.world_offset, float)
    values = []
    for x, z in json.loads(sys.argv[4]):
        o = np.array([x, 0.5, z]) - offset
        cam = _core.Camera(tuple(o), (1, 0, 0), (0, 0, 1), (0, -1, 0), 1e-4, 1e-4, 1, 1, orthographic=True)
        img = scene.render_tile(0, 0, 1, 1, width=1, height=1, spp=1, threads=2, integrator="radiosity",
                                scene_product=product, camera=cam)
        values.append(float(img[0, 0, :3].mean()))
    out["values"] = values
print(json.dumps(out))
"""

NOTE = ("The default's error was the display's: element means interpolated at the vertices (each the mean of "
        "the elements there) flatten the peak under a light and pull the plane's borders inward, and the ambient "
        "term spread 1e-3 of unshot power over a scene whose light escapes. Now the direct light is evaluated at "
        "each vertex, the mesh is refined where that interpolation misses the direct light at an element's centroid "
        "by 0.5 % (at most 8192 elements, no solve between rounds), the refined mesh is shot by rays at the uniform "
        "mesh's ray count, and the ambient term is scaled by the share of shot power that lands "
        "(docs/integrators.md, radiosity). The sphere light's residue is the NEE's noise at the vertices "
        "(16 x light_samples samples).")

POINTS = [(0.0, 0.0), (0.37, -0.21), (0.8, 0.55), (1.9, 0.1), (-1.93, -1.9), (1.3, -1.7)]
LUM = [0.2126, 0.7152, 0.0722]
REGIONS = {"back": (8, 18, 22, 42), "left": (16, 40, 2, 9), "right": (16, 40, 55, 62),
           "ceiling": (3, 8, 8, 22), "floor": (58, 63, 4, 20)}


def lambert_factor(x, n, polygon):
    import math
    import numpy as np
    r = [np.asarray(p, float) - x for p in polygon]
    total = 0.0
    for a, b in zip(r, r[1:] + r[:1]):
        c = np.cross(a, b)
        total += math.atan2(np.linalg.norm(c), float(np.dot(a, b))) * float(np.dot(c / np.linalg.norm(c), n))
    return abs(total) / (2 * math.pi)


def lit_plane(folder: Path, light: str):
    import math
    import numpy as np
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade
    path = folder / f"plane_{light}.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)

    def mesh(prim, points, material=None):
        m = UsdGeom.Mesh.Define(stage, prim)
        m.CreatePointsAttr([Gf.Vec3f(*p) for p in points])
        m.CreateFaceVertexCountsAttr([len(points)])
        m.CreateFaceVertexIndicesAttr(list(range(len(points))))
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        if material is not None:
            UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
        return m

    mesh("/Floor", [(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)]).CreateDisplayColorAttr([Gf.Vec3f(0.5, 0.5, 0.5)])
    if light == "rect":
        L = 3.0
        rect = UsdLux.RectLight.Define(stage, "/Light")
        rect.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
        rect.AddRotateXOp().Set(-90.0)
        rect.CreateWidthAttr(1.0)
        rect.CreateHeightAttr(1.0)
        rect.CreateIntensityAttr(L)
        polygon = [(-0.5, 1, -0.5), (0.5, 1, -0.5), (0.5, 1, 0.5), (-0.5, 1, 0.5)]
    elif light == "mesh":
        L = 2.0
        UsdLux.DistantLight.Define(stage, "/EmissionOnly").CreateIntensityAttr(0.0)
        mat = UsdShade.Material.Define(stage, "/Lamp")
        shader = UsdShade.Shader.Define(stage, "/Lamp/Surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(L, L, L))
        shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        polygon = [(0.6 * math.cos(math.pi * k / 3), 1, 0.6 * math.sin(math.pi * k / 3)) for k in range(6)]
        mesh("/Hexagon", polygon, mat)
    else:
        L = 4.0
        sphere = UsdLux.SphereLight.Define(stage, "/Light")
        sphere.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
        sphere.CreateRadiusAttr(0.2)
        sphere.CreateIntensityAttr(L)
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0.5, 0))
    cam.AddRotateXOp().Set(-90.0)
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(8, 8))
    settings.CreateCameraRel().SetTargets([cam.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    stage.GetRootLayer().Save()

    def radiance(x, z):
        if light == "sphere":
            d2 = x * x + z * z + 1.0
            return 0.5 * L * 0.04 * (1 / math.sqrt(d2)) / d2
        return 0.5 * L * lambert_factor(np.array([x, 0.0, z]), np.array([0.0, 1.0, 0.0]), polygon)

    return path, radiance


def child(core: str, kind: str, path: Path, arg: str) -> dict:
    r = subprocess.run([sys.executable, "-c", CHILD, core, kind, str(path), arg], capture_output=True, text=True,
                       cwd=REPO, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def region_means(img):
    return {k: float((img[r0:r1, c0:c1, :3] @ LUM).mean()) for k, (r0, r1, c0, c1) in REGIONS.items()}


def main() -> None:
    import numpy as np
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline", default="", help="another build's _core*.so, measured beside this one")
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args()
    builds = {"this build": ""} | ({"baseline": args.baseline} if args.baseline else {})
    tmp = Path(tempfile.mkdtemp())
    results: dict = {}
    lines = ["# Radiosity's default: error and cost (benchmarks/radiosity_default.py)", "",
             "Every setting at its default (no element size chosen); 2 threads; solve time the median of "
             f"{args.reps} fresh processes (the machine is shared: times are indicative).", "",
             "## Lit planes: error at 6 points against the closed form", "",
             "| build | light | elements | solve s | " + " | ".join(f"({x}, {z})" for x, z in POINTS) + " | worst |",
             "|---|---|---|---|" + "---|" * (len(POINTS) + 1)]
    for light in ("rect", "mesh", "sphere"):
        path, radiance = lit_plane(tmp, light)
        expected = [radiance(x, z) for x, z in POINTS]
        for name, core in builds.items():
            runs = [child(core, "plane", path, json.dumps(POINTS)) for _ in range(args.reps)]
            errors = [v / e - 1 for v, e in zip(runs[0]["values"], expected)]
            solve = statistics.median(r["solve_s"] for r in runs)
            results[f"{name}/{light}"] = {"elements": runs[0]["elements"], "solve_s": solve, "errors": errors}
            lines.append(f"| {name} | {light} | {runs[0]['elements']} | {solve:.2f} | " +
                         " | ".join(f"{100 * e:+.2f} %" for e in errors) +
                         f" | {100 * max(abs(e) for e in errors):.2f} % |")
    from tessera_renderer import Scene, load_scene
    import dataclasses
    cornell = Scene(dataclasses.replace(load_scene(str(CORNELL)).data, material_params=None))
    ref = region_means(cornell.render_tile(0, 0, 64, 64, width=64, height=64, spp=1024, threads=2,
                                           integrator="path", seed=1))
    lines += ["", "## Cornell box (Lambertian): wall regions against path at 1024 spp", "",
              "| build | elements | solve s | " + " | ".join(REGIONS) + " | worst |",
              "|---|---|---|" + "---|" * (len(REGIONS) + 1)]
    for name, core in builds.items():
        runs = [child(core, "cornell", CORNELL, str(tmp / "cornell.npy")) for _ in range(args.reps)]
        means = region_means(np.load(tmp / "cornell.npy"))
        errors = {k: means[k] / ref[k] - 1 for k in REGIONS}
        solve = statistics.median(r["solve_s"] for r in runs)
        results[f"{name}/cornell"] = {"elements": runs[0]["elements"], "solve_s": solve, "errors": errors}
        lines.append(f"| {name} | {runs[0]['elements']} | {solve:.2f} | " +
                     " | ".join(f"{100 * errors[k]:+.2f} %" for k in REGIONS) +
                     f" | {100 * max(abs(e) for e in errors.values()):.2f} % |")
    lines += ["", NOTE]
    write_results("radiosity-default", results, lines)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
