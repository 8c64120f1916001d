"""Texture filtering end to end: a pixel that covers many checks of a checker texture shows
the checker's average, the render does not depend on the thread count, and point lookups
(TESSERA_TEXTURE_FILTER=point, read once per process: run in a child) alias where filtered
lookups do not.

The rig: a floor under a delta sun of irradiance E straight above, seen straight down by a
narrow camera (rays within 1 degree of the normal), UsdPreviewSurface with ior 1: a pixel
shows albedo / pi * E with the albedo averaged over the pixel (test_textures_instancing.py).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from tessera import render
from tessera_renderer import load_scene
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

E = 3.0
LO, HI = 0.1, 0.8


def checker_floor(tmp_path: Path, name: str, *, hi: float = HI, st_per_unit: float = 100.0,
                  camera_height: float = 1.0, tilt: float = 0.0, res=(8, 8)) -> str:
    """A 256-texel checker of 8-texel squares (lo, hi: 32 squares per st unit) on a 40 x 40
    floor with `st_per_unit` st per unit. The camera (36 mm aperture, focal 1000) at
    `camera_height` looks down, tilted `tilt` degrees toward -z."""
    import OpenImageIO as oiio

    y, x = np.mgrid[0:256, 0:256]
    v = np.where(((x // 8) + (y // 8)) % 2 == 0, LO, hi).astype(np.float32)
    buf = oiio.ImageBuf(np.ascontiguousarray(np.repeat(v[:, :, None], 3, axis=2)))
    assert buf.write(str(tmp_path / f"{name}.exr")), buf.geterror()
    stage = new_stage(tmp_path / f"{name}.usda")
    mat = add_material(stage, "/Looks/M")
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface"))
    surface.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.0)
    tex = UsdShade.Shader.Define(stage, "/Looks/M/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{name}.exr")
    reader = UsdShade.Shader.Define(stage, "/Looks/M/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    pts = [(-20, 0, -20), (-20, 0, 20), (20, 0, 20), (20, 0, -20)]
    mesh = add_mesh(stage, "/Floor", pts, [4], [0, 1, 2, 3], mat)
    st = [(px * st_per_unit + 0.3, -pz * st_per_unit + 0.3) for px, _, pz in pts]
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set([Gf.Vec2f(*s) for s in st])
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.AddRotateXOp().Set(-90.0)
    sun.CreateAngleAttr(0.0)
    sun.CreateIntensityAttr(E)
    cam = add_camera(stage, "/Cam", (0, camera_height, 0), focal=1000.0, haperture=36.0, vaperture=36.0)
    cam.AddRotateXOp().Set(-90.0 + tilt)
    add_render_settings(stage, cam, res)
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


def floor_pixels(path: str, point: bool = False) -> np.ndarray:
    """The floor's pixels (R), rendered at 4 spp, max depth 1; `point` in a child process
    with TESSERA_TEXTURE_FILTER=point."""
    if not point:
        return load_scene(path).render_tile(0, 0, 8, 8, spp=4, max_depth=1)[..., 0]
    code = ("import json, sys; from tessera_renderer import load_scene; "
            "print(json.dumps(load_scene(sys.argv[1]).render_tile(0, 0, 8, 8, spp=4, max_depth=1)[..., 0].tolist()))")
    out = subprocess.run([sys.executable, "-c", code, path], capture_output=True, text=True, check=True,
                         env={**os.environ, "TESSERA_TEXTURE_FILTER": "point"})
    return np.array(json.loads(out.stdout.splitlines()[-1]))


def test_a_pixel_over_many_checks_shows_the_checker_average(tmp_path):
    """Each pixel (0.036 / 8 units wide at height 1, 100 st per unit: 0.45 st, 14 checks per
    side; the footprint a quarter of that, 3.6 checks) shows (lo + hi) / 2 / pi * E to 1 %. The smallest error this detects is a 2 % shift
    of the average: a checker whose bright squares are 0.018 brighter fails the same check,
    and so do point lookups (each sample reads one square: pixels alias)."""
    expected = (LO + HI) / 2 / math.pi * E
    got = floor_pixels(checker_floor(tmp_path, "fine"))
    assert np.max(np.abs(got / expected - 1)) < 0.01, got / expected
    brighter = floor_pixels(checker_floor(tmp_path, "brighter", hi=HI + 0.018))
    assert np.max(np.abs(brighter / expected - 1)) >= 0.01
    point = floor_pixels(checker_floor(tmp_path, "point"), point=True)
    assert np.max(np.abs(point / expected - 1)) > 0.1


def test_magnified_texture_reads_as_without_filtering(tmp_path):
    """Magnified (0.01 st per unit: a pixel covers 0.005 texels), filtered and point lookups
    give the same image bit for bit."""
    path = checker_floor(tmp_path, "magnified", st_per_unit=0.01)
    np.testing.assert_array_equal(floor_pixels(path), floor_pixels(path, point=True))


def test_filtered_render_is_the_same_on_one_thread_and_two(tmp_path):
    """A grazing view (the camera tilted 80 degrees from straight down: footprints 6 times
    longer than wide, about one check) renders bit-identically on 1 and on 2 threads."""
    path = checker_floor(tmp_path, "grazing", tilt=80.0, camera_height=1.0, res=(32, 16), st_per_unit=3.0)
    one = render(path, spp=4, threads=1, variance=False, tile_size=8)
    two = render(path, spp=4, threads=2, variance=False, tile_size=8)
    assert np.array_equal(one.rgba, two.rgba)
    assert np.ptp(one.rgb) > 0.1 * one.rgb.max()  # checks in view, not their flat average
