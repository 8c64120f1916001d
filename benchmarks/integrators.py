"""Integrators at equal sample counts: time, error and efficiency, in one run.

    .venv/bin/python benchmarks/integrators.py [--res 64] [--spp 64] [--seeds 3]

Scenes: the bundled Cornell box (diffuse, no caustics) and the same box with a glass
sphere and a mirror sphere (caustics on the floor). For each of path, bdpt and light:
wall time, relMSE against a reference (bdpt at high spp, rendered in this run) and the
efficiency 1 / (relMSE * seconds), reported relative to path tracing. Medians over seeds
with the half-range as error. This is what `auto` is chosen by (docs/integrators.md).
Writes docs/benchmarks/integrators.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import CORNELL, REPO, rel_mse



def caustic_scene(directory: Path) -> Path:
    """The Cornell box plus a glass sphere (opacity 0, ior 1.5, smooth) and a mirror sphere."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    import shutil

    # The sandbox accepts only relative paths inside the bundle: copy the box beside it.
    shutil.copy(CORNELL, directory / "cornell.usda")
    path = directory / "cornell_caustics.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.GetRootLayer().subLayerPaths.append("cornell.usda")
    for name, pos, inputs in (("Glass", (185, 90, 169), {"opacity": 0.0, "ior": 1.5, "roughness": 0.0}),
                              ("Mirror", (370, 90, 351), {"metallic": 1.0, "roughness": 0.0})):
        mat = UsdShade.Material.Define(stage, f"/Cornell/Looks/{name}")
        shader = UsdShade.Shader.Define(stage, f"/Cornell/Looks/{name}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.95, 0.95, 0.95))
        for key, value in inputs.items():
            shader.CreateInput(key, Sdf.ValueTypeNames.Float).Set(value)
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        sphere = UsdGeom.Sphere.Define(stage, f"/Cornell/Geometry/{name}Sphere")
        sphere.CreateRadiusAttr(80.0)
        sphere.AddTranslateOp().Set(Gf.Vec3d(*pos))
        UsdShade.MaterialBindingAPI.Apply(sphere.GetPrim()).Bind(mat)
    # The blocks would hide the spheres; deactivate them.
    for block in ("short_block", "tall_block"):
        stage.OverridePrim(f"/Cornell/Geometry/{block}").SetActive(False)
    stage.GetRootLayer().Save()
    return path


def render(scene, integrator: str, spp: int, seed: int, res: int) -> tuple[np.ndarray, float]:
    from tessera_base.film import resolve_splats
    from tessera_renderer.film import new_splat_buffer

    splats = new_splat_buffer(res, res)
    start = time.perf_counter()
    rgba = scene.render_tile(0, 0, res, res, width=res, height=res, spp=spp, seed=seed, threads=2,
                             max_depth=32, integrator=integrator, splats=splats)
    seconds = time.perf_counter() - start
    return resolve_splats(rgba, splats, res * res * spp, scene.splat_exponent), seconds


def main() -> int:
    from tessera_renderer import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=2048)
    args = ap.parse_args()
    out: dict = {"res": args.res, "spp": args.spp, "reference": f"bdpt, {args.ref_spp} spp", "scenes": {}}
    lines = ["# Integrators at equal sample counts", "",
             f"Written by `benchmarks/integrators.py`: {args.res}x{args.res}, {args.spp} spp, 2 threads, "
             f"{args.seeds} seeds (median ± half-range); relMSE against bdpt at {args.ref_spp} spp from the "
             "same run; efficiency = 1 / (relMSE x seconds), relative to path.", "",
             "| scene | integrator | seconds | relMSE | efficiency vs path | auto picks |", "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for name, path in (("cornell", CORNELL), ("cornell + glass and mirror spheres", caustic_scene(Path(tmp)))):
            scene = load_scene(path)
            ref, ref_seconds = render(scene, "bdpt", args.ref_spp, 12345, args.res)
            rows = {}
            for integrator in ("path", "bdpt", "light"):
                times, errors = [], []
                for seed in range(args.seeds):
                    img, seconds = render(scene, integrator, args.spp, seed, args.res)
                    times.append(seconds)
                    errors.append(rel_mse(img, ref))
                eff = [1.0 / (e * t) for e, t in zip(errors, times)]
                rows[integrator] = {"seconds": times, "rel_mse": errors, "efficiency": eff}
            base = statistics.median(rows["path"]["efficiency"])
            auto = scene.resolve_integrator("auto")
            for integrator, r in rows.items():
                rel = [e / base for e in r["efficiency"]]
                r["efficiency_vs_path"] = rel

                def fmt(v, digits=3):
                    return f"{statistics.median(v):.{digits}g} ± {(max(v) - min(v)) / 2:.2g}"
                lines.append(f"| {name} | {integrator} | {fmt(r['seconds'])} | {fmt(r['rel_mse'])} | "
                             f"{fmt(rel)} | {'yes' if integrator == auto else ''} |")
                print(lines[-1], flush=True)
            out["scenes"][name] = {"reference_seconds": ref_seconds, "auto": auto, "rows": rows}
    dest = REPO / "docs" / "benchmarks"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "integrators.json").write_text(json.dumps(out, indent=2) + "\n")
    (dest / "integrators.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
