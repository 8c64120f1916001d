"""Texture filtering: aliasing, memory and render time of filtered lookups (a mip-map per
image, each lookup averaged over the pixel's footprint) against the renderer before them
(bilinear point lookups on the whole image, no mip-maps): the `_core` module of another
build (--baseline-core, default main's build at /work/main; copied first, so a rebuild
there does not change it mid-run), loaded in place of this tree's (common.LOAD_CORE).

    .venv/bin/python benchmarks/textures.py [--repeats 5] [--big 2048] [--ref-spp 2048]

1. Aliasing: a checker plane running to the horizon under a white dome, 256 x 128, path at
   16 spp, relMSE of the image and of its albedo layer against a supersampled reference
   (the baseline's point lookups at ref-spp, two halves with different seeds, whose own
   noise is subtracted: tessera_tools.bench_stats.reference_noise).
2. Memory: peak RSS of a process that loads a scene of 8 textures of big x big texels
   (random RGB, 8-bit TIFF, made here in a temporary folder, never committed) and renders
   a 64 x 64 image at 1 spp.
3. Time: the checker plane at 16 spp, each measurement a fresh child process (load, a
   warm-up tile, one timed render), the two sides alternating A B B A ... per repeat; the
   ratio is taken per repeat (median and half-range).

Results go to docs/benchmarks/textures.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from common import LOAD_CORE, REPO, fmt, rel_mse, summary, write_results
from tessera_tools.bench_stats import reference_noise

CHECKER_PLANE = """#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 1
)
def Xform "World"
{
    def Camera "Cam"
    {
        float focalLength = 18
        float horizontalAperture = 36
        float verticalAperture = 18
        double3 xformOp:translate = (0, 1, 4)
        float xformOp:rotateX = -6
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
    }
    def DomeLight "Sky"
    {
        float inputs:intensity = 1
    }
    def Mesh "Plane"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-200, 0, 5), (200, 0, 5), (200, 0, -1000), (-200, 0, -1000)]
        texCoord2f[] primvars:st = [(0, 0), (200, 0), (200, 502.5), (0, 502.5)] (interpolation = "vertex")
        rel material:binding = </World/Looks/Checker>
    }
    def Scope "Looks"
    {
        def Material "Checker"
        {
            token outputs:surface.connect = </World/Looks/Checker/Surface.outputs:surface>
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </World/Looks/Checker/Tex.outputs:rgb>
                float inputs:roughness = 1
                float inputs:ior = 1
                token outputs:surface
            }
            def Shader "Tex"
            {
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @checker.png@
                float2 inputs:st.connect = </World/Looks/Checker/Reader.outputs:result>
                token inputs:sourceColorSpace = "raw"
                token inputs:wrapS = "repeat"
                token inputs:wrapT = "repeat"
                float3 outputs:rgb
            }
            def Shader "Reader"
            {
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }
        }
    }
}
"""

# Eight quads in a row, each with its own texture, filling a camera's view.
BIG_TEXTURES_HEAD = """#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 1
)
def Xform "World"
{
    def Camera "Cam"
    {
        float focalLength = 18
        float horizontalAperture = 36
        float verticalAperture = 36
        double3 xformOp:translate = (0, 0, 12)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def DomeLight "Sky"
    {
        float inputs:intensity = 1
    }
"""

BIG_TEXTURE_QUAD = """
    def Mesh "Quad{k}"
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [({x0}, -1, 0), ({x1}, -1, 0), ({x1}, 1, 0), ({x0}, 1, 0)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        rel material:binding = </World/M{k}>
    }}
    def Material "M{k}"
    {{
        token outputs:surface.connect = </World/M{k}/Surface.outputs:surface>
        def Shader "Surface"
        {{
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor.connect = </World/M{k}/Tex.outputs:rgb>
            token outputs:surface
        }}
        def Shader "Tex"
        {{
            uniform token info:id = "UsdUVTexture"
            asset inputs:file = @big{k}.tif@
            float2 inputs:st.connect = </World/M{k}/Reader.outputs:result>
            float3 outputs:rgb
        }}
        def Shader "Reader"
        {{
            uniform token info:id = "UsdPrimvarReader_float2"
            string inputs:varname = "st"
            float2 outputs:result
        }}
    }}
"""

# One measurement in a fresh process: argv = core mode scene out.npz spp seed res; prints one
# JSON line.
_CHILD = LOAD_CORE + r"""
import json, resource, sys, time
import numpy as np
from tessera import render
from tessera_renderer import load_scene
mode, scene, out, spp, seed, res = sys.argv[2:8]
w, h = (int(v) for v in res.split("x"))
loaded = load_scene(scene)
if mode == "time":
    render(loaded, spp=1, res=(16, 8), variance=False)  # warm-up: first-touch costs out of the timing
t0 = time.perf_counter()
img = render(loaded, spp=int(spp), seed=int(seed), res=(w, h), aovs=["albedo"] if mode == "image" else [],
             variance=False)
seconds = time.perf_counter() - t0
if mode == "image":
    np.savez(out, rgb=img.rgb, albedo=img.layers["albedo"][..., :3])
print(json.dumps({"seconds": seconds, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "texture_mb": getattr(loaded, "texture_bytes", 0) / 2**20}))
"""


def child(mode: str, scene: Path, core: str, *, out: Path | None = None, spp: int = 16, seed: int = 0,
          res: str = "256x128") -> dict:
    """One measurement; core "" is this tree's build, else the path of another `_core`."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    env.pop("TESSERA_TEXTURE_FILTER", None)
    p = subprocess.run([sys.executable, "-c", _CHILD, core, mode, str(scene), str(out or ""), str(spp), str(seed),
                        res], env=env, cwd=REPO, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"benchmark child failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def write_checker(folder: Path) -> Path:
    import OpenImageIO as oiio

    # 64 x 64 texels, 8-texel checks of 0.1 and 0.8: each texture repeat spans 2 x 2 units.
    y, x = np.mgrid[0:64, 0:64]
    v = np.where(((x // 8) + (y // 8)) % 2 == 0, 0.1, 0.8).astype(np.float32)
    buf = oiio.ImageBuf(np.ascontiguousarray(np.repeat(v[:, :, None], 3, axis=2)))
    buf.set_write_format(oiio.UINT16)
    assert buf.write(str(folder / "checker.png")), buf.geterror()
    scene = folder / "checker_plane.usda"
    scene.write_text(CHECKER_PLANE)
    return scene


def write_big_textures(folder: Path, size: int) -> Path:
    import OpenImageIO as oiio

    rng = np.random.default_rng(1)
    text = BIG_TEXTURES_HEAD
    for k in range(8):
        pixels = rng.integers(0, 256, size=(size, size, 3), dtype=np.uint8)
        buf = oiio.ImageBuf(pixels)
        assert buf.write(str(folder / f"big{k}.tif")), buf.geterror()
        del pixels, buf
        text += BIG_TEXTURE_QUAD.format(k=k, x0=-8 + 2 * k, x1=-6 + 2 * k)
    text += "}\n"
    scene = folder / "big_textures.usda"
    scene.write_text(text)
    return scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--big", type=int, default=2048, help="texels per side of the 8 big textures")
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--baseline-core", default="/work/main/build/cp311-cp311-linux_x86_64/renderer/"
                    "_core.cpython-311-x86_64-linux-gnu.so", help="the _core module of the build before filtering")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="tessera-textures-bench-") as tmp:
        tmp = Path(tmp)
        baseline = tmp / Path(args.baseline_core).name
        shutil.copyfile(args.baseline_core, baseline)
        sides = {"before": str(baseline), "filtered": ""}
        plane = write_checker(tmp)

        # 1. Aliasing.
        halves = []
        for seed in (101, 202):
            child("image", plane, sides["before"], out=tmp / f"ref{seed}.npz", spp=args.ref_spp // 2, seed=seed)
            halves.append(np.load(tmp / f"ref{seed}.npz"))
        errors = {}
        for layer in ("rgb", "albedo"):
            a, b = halves[0][layer], halves[1][layer]
            ref = (a + b) / 2
            floor, floor_se = reference_noise(a, b)
            errors[layer] = {"reference_noise": floor, "reference_noise_se": floor_se}
            for name, core in sides.items():
                if layer == "rgb":
                    child("image", plane, core, out=tmp / f"{name}.npz", spp=16, seed=7)
                img = np.load(tmp / f"{name}.npz")[layer]
                errors[layer][name] = rel_mse(img, ref) - floor
        # 2. Memory.
        big = write_big_textures(tmp, args.big)
        memory = {name: child("memory", big, core, spp=1, res="64x64") for name, core in sides.items()}
        for f in tmp.glob("big*.tif"):
            f.unlink()

        # 3. Time, interleaved.
        times = {"before": [], "filtered": []}
        ratios = []
        for r in range(args.repeats):
            order = ("before", "filtered") if r % 2 == 0 else ("filtered", "before")
            got = {name: child("time", plane, sides[name])["seconds"] for name in order}
            for name in got:
                times[name].append(got[name])
            ratios.append(got["filtered"] / got["before"])

    t = {name: summary(v) for name, v in times.items()}
    ratio = summary(ratios)
    texel_mb = 8 * args.big * args.big * 3 * 4 / 2**20
    data = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "aliasing_relmse": errors, "peak_rss_mb": memory, "big_texture_texels": args.big,
            "float_texels_mb": texel_mb, "seconds": t, "time_ratio_filtered_over_before": ratio,
            "ref_spp": args.ref_spp, "baseline_core": args.baseline_core}
    lines = [
        "# Texture filtering: aliasing, memory, time",
        "",
        "`benchmarks/textures.py` (numbers in `textures.json`). Filtered: a mip-map per image and",
        "each lookup averaged over the pixel's footprint (docs/scene-translation.md, \"Texture",
        "filtering\"); before: the build before it (bilinear point lookups, no mip-maps).",
        f"Machine: {data['machine']}, {data['cpus']} cores shared with other work (times spread).",
        "",
        "## Aliasing: a checker plane to the horizon",
        "",
        f"256 x 128, path at 16 spp against the point lookups of before at {args.ref_spp} spp (two halves;",
        "their own noise, given, is subtracted). A 64-texel checker of 8-texel squares repeats",
        "every 2 units on a plane 1 km deep, seen from 1 unit above.",
        "",
        "| layer | relMSE before | relMSE filtered | reference noise |",
        "|---|---|---|---|",
    ]
    for layer, e in errors.items():
        lines.append(f"| {layer} | {e['before']:.4g} | {e['filtered']:.4g} | {e['reference_noise']:.2g} |")
    lines += [
        "",
        "## Memory: 8 textures of {0} x {0} texels".format(args.big),
        "",
        f"Peak RSS of loading the scene and rendering 64 x 64 at 1 spp. The texels alone, as float",
        f"RGB: {texel_mb:.0f} MB; the mip-maps add a third of that. No cache bounds them",
        "(docs/scene-translation.md, \"Texture filtering\").",
        "",
        "| build | peak RSS (MB) | texels held by the core (MB, `Scene.texture_bytes`) |",
        "|---|---|---|",
        f"| before | {memory['before']['peak_rss_mb']:.0f} | (not reported) |",
        f"| filtered | {memory['filtered']['peak_rss_mb']:.0f} | {memory['filtered']['texture_mb']:.0f} |",
        "",
        "The peak is about three times the texels: besides the core's float copy, the images are",
        "held decoded on the way in (Python's arrays; not broken down here). A texture cache",
        "with a budget (OpenImageIO's TextureSystem) is not used, so 8 textures of 8192² would",
        "need about four times these numbers; this machine's share could not hold them.",
        "",
        "## Render time: the checker plane, 256 x 128, 16 spp",
        "",
        f"Fresh child per measurement, sides alternating, {args.repeats} repeats (median ± half-range).",
        "",
        f"- before: {fmt(t['before'], ' s')}",
        f"- filtered: {fmt(t['filtered'], ' s')}",
        f"- filtered / before, per repeat: {fmt(ratio)}",
        "",
        "Every shading point of this image is textured and most footprints are long (up to 16",
        "probes of two levels each): a scene with fewer textured pixels pays less. At equal time",
        "(before at about 1.4 times the samples, error falling as 1/spp) filtered is still about",
        "twice as accurate on the checker plane.",
    ]
    write_results("textures", data, lines)


if __name__ == "__main__":
    main()
