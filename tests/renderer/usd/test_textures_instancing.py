"""Textures and instancing end to end: real image files written with OpenImageIO, USD
written with pxr, rendered by the core, checked against values worked out independently.

A UsdPreviewSurface with ior 1 seen and lit along its normal has Schlick Fresnel exactly 0,
so it reflects albedo / pi * E: a textured floor under a delta DistantLight of irradiance
E straight above shows texel / pi * E.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from tessera_renderer import load_scene
from tessera_renderer.scene_blob import scene_from_blob, translate_to_blob
from conftest import SHARED_SCENES
from tessera_renderer.usd import translate_stage
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

E = 3.0
SCENES = SHARED_SCENES


def srgb_to_linear(v: float) -> float:
    """IEC 61966-2-1, written out here independently of the core."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def write_image(path: Path, pixels: np.ndarray) -> str:
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(np.ascontiguousarray(pixels))
    assert buf.write(str(path)), buf.geterror()
    return str(path)


def save(stage) -> str:
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


def textured_floor(tmp_path: Path, name: str, file: str | None, *, input_name: str = "diffuseColor",
                   output: str = "rgb", tex_inputs: dict | None = None, center_st=(0.25, 0.25),
                   transform2d: dict | None = None, diffuse=(0.18, 0.18, 0.18), st_values=None) -> str:
    """A 2 x 2 floor (y = 0, facing +y) whose st puts the centre at `center_st` (s along
    +x, t along -z), a UsdPreviewSurface with ior 1 whose `input_name` reads `file`, a
    delta sun of irradiance E straight above, a narrow camera looking down at the centre."""
    stage = new_stage(tmp_path / f"{name}.usda")
    mat = add_material(stage, "/Looks/M", diffuse)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface"))
    surface.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.0)
    if file is not None:
        tex = UsdShade.Shader.Define(stage, "/Looks/M/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
        for key, (type_name, value) in (tex_inputs or {}).items():
            tex.CreateInput(key, type_name).Set(value)
        reader = UsdShade.Shader.Define(stage, "/Looks/M/Reader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        st_source = reader.ConnectableAPI()
        if transform2d is not None:
            xf = UsdShade.Shader.Define(stage, "/Looks/M/Xf")
            xf.CreateIdAttr("UsdTransform2d")
            xf.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
            xf.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*transform2d.get("scale", (1, 1))))
            xf.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(transform2d.get("rotation", 0.0))
            xf.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set(
                Gf.Vec2f(*transform2d.get("translation", (0, 0))))
            st_source = xf.ConnectableAPI()
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st_source, "result")
        type_name = Sdf.ValueTypeNames.Normal3f if input_name == "normal" else (
            Sdf.ValueTypeNames.Color3f if input_name.endswith("Color") else Sdf.ValueTypeNames.Float)
        surface.CreateInput(input_name, type_name).ConnectToSource(tex.ConnectableAPI(), output)
    pts = [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]
    mesh = add_mesh(stage, "/Floor", pts, [4], [0, 1, 2, 3], mat)
    cs, ct = center_st
    st = st_values or [((x + 1) / 2 - 0.5 + cs, (1 - z) / 2 - 0.5 + ct) for x, _, z in pts]
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set([Gf.Vec2f(*v) for v in st])
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.AddRotateXOp().Set(-90.0)   # -Z turned to travel down, along -Y
    sun.CreateAngleAttr(0.0)        # delta: intensity is the irradiance
    sun.CreateIntensityAttr(E)
    cam = add_camera(stage, "/Cam", (0, 1, 0), focal=1000.0, haperture=1.0, vaperture=1.0)
    cam.AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (4, 4))
    return save(stage)


def centre(path: str, **kw) -> np.ndarray:
    scene = load_scene(path, **kw)
    return scene.render_tile(0, 0, 4, 4, spp=4, max_depth=1)[..., :3].reshape(-1, 3).mean(axis=0)


# -- textures --------------------------------------------------------------------------
def test_8bit_colour_texture_is_srgb_decoded_albedo_times_irradiance(tmp_path):
    rgb8 = (128, 64, 200)
    file = write_image(tmp_path / "c.png", np.tile(np.array(rgb8, np.uint8), (4, 4, 1)))
    got = centre(textured_floor(tmp_path, "srgb", "./c.png"))
    expected = [srgb_to_linear(v / 255) / math.pi * E for v in rgb8]
    np.testing.assert_allclose(got, expected, rtol=1e-4)
    assert Path(file).is_file()
    # sourceColorSpace raw: the same file read as linear data.
    raw = textured_floor(tmp_path, "raw", "./c.png",
                         tex_inputs={"sourceColorSpace": (Sdf.ValueTypeNames.Token, "raw")})
    np.testing.assert_allclose(centre(raw), [v / 255 / math.pi * E for v in rgb8], rtol=1e-4)
    # Negative control: without the texture the constant diffuse colour shows.
    np.testing.assert_allclose(centre(textured_floor(tmp_path, "none", None)), [0.18 / math.pi * E] * 3, rtol=1e-4)


def test_8bit_grey_texture_under_auto_is_linear(tmp_path):
    write_image(tmp_path / "g.png", np.full((4, 4, 1), 100, np.uint8))
    got = centre(textured_floor(tmp_path, "grey", "./g.png"))
    np.testing.assert_allclose(got, [100 / 255 / math.pi * E] * 3, rtol=1e-4)


# A 2x1 float image: texel 0 = 0.2, texel 1 = 1.0. The floor's centre has s = 1.25 (the
# centre of texel 2, one period right of texel 0) and t = 0.25.
@pytest.mark.parametrize("wrap,value", [
    ("repeat", 0.2), ("useMetadata", 0.2),   # period 1: texel 0
    ("clamp", 1.0),                          # the last texel
    ("mirror", 1.0),                         # texel 2 mirrors texel 1
    ("black", 0.0),
])
def test_wrap_modes_outside_the_unit_square(tmp_path, wrap, value):
    img = np.array([[[0.2] * 3, [1.0] * 3]], np.float32)
    write_image(tmp_path / "ramp.exr", img)
    path = textured_floor(tmp_path, f"wrap_{wrap}", "./ramp.exr", center_st=(1.25, 0.25),
                          tex_inputs={"wrapS": (Sdf.ValueTypeNames.Token, wrap)})
    # The centre sits on a texel centre, the kink of the bilinear tent: the camera's tiny
    # footprint (+-0.0005 texels) reads up to 0.1 % of the neighbour.
    np.testing.assert_allclose(centre(path), [value / math.pi * E] * 3, atol=1e-3)


def test_transform2d_scales_rotates_then_translates_st(tmp_path):
    """st = (1.25, 0.25) -> x (2, 1) = (2.5, 0.25) -> rotated 90 degrees counter-clockwise
    = (-0.25, 2.5) -> + (0.5, -2.25) = (0.25, 0.25): texel 0 under clamp. Turning the
    other way would land at s = 0.75 (texel 1), and no transform at s = 1.25 (texel 1)."""
    write_image(tmp_path / "ramp.exr", np.array([[[0.2] * 3, [1.0] * 3]], np.float32))
    clamp = {"wrapS": (Sdf.ValueTypeNames.Token, "clamp"), "wrapT": (Sdf.ValueTypeNames.Token, "clamp")}
    with_xf = textured_floor(tmp_path, "xf", "./ramp.exr", center_st=(1.25, 0.25), tex_inputs=clamp,
                             transform2d={"scale": (2, 1), "rotation": 90.0, "translation": (0.5, -2.25)})
    without = textured_floor(tmp_path, "noxf", "./ramp.exr", center_st=(1.25, 0.25), tex_inputs=clamp)
    np.testing.assert_allclose(centre(with_xf), [0.2 / math.pi * E] * 3, atol=1e-3)  # see the wrap test
    np.testing.assert_allclose(centre(without), [1.0 / math.pi * E] * 3, atol=1e-3)


def test_scale_bias_and_single_channel_outputs(tmp_path):
    """roughness <- texture r * 0.5 + 0.25 ... checked through diffuseColor, whose value is
    visible directly: output g of (0.1, 0.4, 0.7) scaled by 2 and biased by 0.05 = 0.85."""
    write_image(tmp_path / "c.exr", np.tile(np.array([0.1, 0.4, 0.7], np.float32), (2, 2, 1)))
    path = textured_floor(tmp_path, "sb", "./c.exr", output="g", tex_inputs={
        "scale": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(2, 2, 2, 1)),
        "bias": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.05, 0.05, 0.05, 0))})
    np.testing.assert_allclose(centre(path), [0.85 / math.pi * E] * 3, rtol=1e-4)


def test_missing_texture_file_uses_the_fallback_with_a_warning(tmp_path):
    path = textured_floor(tmp_path, "missing", "./nowhere.png", tex_inputs={
        "fallback": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.3, 0.5, 0.7, 1))})
    scene = load_scene(path)
    assert any("nowhere.png" in w and "fallback" in w for w in scene.warnings)
    got = scene.render_tile(0, 0, 4, 4, spp=4, max_depth=1)[..., :3].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(got, [0.3 / math.pi * E, 0.5 / math.pi * E, 0.7 / math.pi * E], rtol=1e-4)


def test_unreadable_texture_file_uses_the_fallback_with_a_warning(tmp_path):
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not an image")
    path = textured_floor(tmp_path, "broken", "./broken.png", tex_inputs={
        "fallback": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.4, 0.4, 0.4, 1))})
    scene = load_scene(path)
    assert any("broken.png" in w for w in scene.warnings)
    got = scene.render_tile(0, 0, 4, 4, spp=4, max_depth=1)[..., :3]
    np.testing.assert_allclose(got.reshape(-1, 3).mean(axis=0), [0.4 / math.pi * E] * 3, rtol=1e-4)


def test_nan_texture_coordinates_are_reported_and_render_finite(tmp_path):
    write_image(tmp_path / "c.exr", np.full((2, 2, 3), 0.5, np.float32))
    st = [(0, 0), (float("nan"), 0), (1, 1), (1, 0)]
    path = textured_floor(tmp_path, "nan", "./c.exr", st_values=st)
    scene = load_scene(path)
    assert any("NaN/Inf texture coordinates" in w for w in scene.warnings)
    assert np.isfinite(scene.render_tile(0, 0, 4, 4, spp=4)).all()


def test_udim_tiles_pick_the_tile_under_st_and_survive_the_blob(tmp_path):
    write_image(tmp_path / "u.1001.png", np.full((4, 4, 3), 40, np.uint8))
    write_image(tmp_path / "u.1002.png", np.full((4, 4, 3), 200, np.uint8))
    path = textured_floor(tmp_path, "udim", "./u.<UDIM>.png", center_st=(1.5, 0.5))
    expected = [srgb_to_linear(200 / 255) / math.pi * E] * 3
    np.testing.assert_allclose(centre(path), expected, rtol=1e-4)
    from_blob = scene_from_blob(translate_to_blob(path))
    got = from_blob.render_tile(0, 0, 4, 4, spp=4, max_depth=1)[..., :3].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(got, expected, rtol=1e-4)
    # The other tile, for contrast.
    np.testing.assert_allclose(centre(textured_floor(tmp_path, "udim1", "./u.<UDIM>.png", center_st=(0.5, 0.5))),
                               [srgb_to_linear(40 / 255) / math.pi * E] * 3, rtol=1e-4)


def normal_map_value(tmp_path, name, image: np.ndarray, ext: str) -> float:
    write_image(tmp_path / f"{name}.{ext}", image)
    path = textured_floor(tmp_path, name, f"./{name}.{ext}", input_name="normal", diffuse=(0.5, 0.5, 0.5),
                          tex_inputs={"scale": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(2, 2, 2, 1)),
                                      "bias": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(-1, -1, -1, 0))})
    return float(centre(path)[0])


def test_flat_normal_map_changes_nothing_and_a_tilted_one_shades_like_tilted_geometry(tmp_path):
    plain = float(centre(textured_floor(tmp_path, "plain", None, diffuse=(0.5, 0.5, 0.5)))[0])
    assert plain == pytest.approx(0.5 / math.pi * E, rel=1e-4)
    # An 8-bit (128, 128, 255) map (raw under auto: data, not colour) decodes to a normal
    # 0.2 degrees off (0, 0, 1).
    flat = normal_map_value(tmp_path, "flat", np.tile(np.array([128, 128, 255], np.uint8), (2, 2, 1)), "png")
    assert flat == pytest.approx(plain, rel=1e-4)
    tilt = math.radians(30)
    encoded = np.array([0.5 + 0.5 * math.sin(tilt), 0.5, 0.5 + 0.5 * math.cos(tilt)], np.float32)
    tilted = normal_map_value(tmp_path, "tilted", np.tile(encoded, (2, 2, 1)), "exr")
    c = math.cos(tilt)
    fresnel = (1 - c) ** 5   # Schlick with F0 = 0, at the 30 degrees the light and camera make
    assert tilted == pytest.approx(0.5 / math.pi * E * c * (1 - fresnel) ** 2, rel=1e-4)


# -- instancing ------------------------------------------------------------------------
def block_z(a, va, b, vb, spp, block=8):
    """Largest |z| over blocks of block x block pixels between two renders' block means,
    each with its per-pixel sample variance (Mitsuba-style z-test on aggregates)."""
    h, w = a.shape[:2]
    zs = []
    for y in range(0, h, block):
        for x in range(0, w, block):
            sa, sb = a[y:y + block, x:x + block, :3], b[y:y + block, x:x + block, :3]
            n = sa.shape[0] * sa.shape[1]
            var = (va[y:y + block, x:x + block].sum(axis=(0, 1)) + vb[y:y + block, x:x + block].sum(axis=(0, 1)))
            var = var / spp / n ** 2
            diff = sa.mean(axis=(0, 1)) - sb.mean(axis=(0, 1))
            zs.append(np.max(np.abs(diff) / np.sqrt(np.maximum(var, 1e-12))))
    return float(max(zs))


def _instancer_scene(tmp_path) -> str:
    """A PointInstancer placing a textured box (st, smooth normals) with rotations,
    non-uniform scales and a mirror, and an emissive quad twice (once mirrored), over a
    floor, lit also by a sphere light."""
    write_image(tmp_path / "checker.png",
                (np.indices((8, 8)).sum(axis=0) % 2)[:, :, None].repeat(3, axis=2).astype(np.uint8) * 180 + 40)
    stage = new_stage(tmp_path / "pi.usda")
    mat = add_material(stage, "/Looks/Box", (0.5, 0.5, 0.5))
    tex = UsdShade.Shader.Define(stage, "/Looks/Box/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./checker.png")
    reader = UsdShade.Shader.Define(stage, "/Looks/Box/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/Box/Surface")).GetInput("diffuseColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    glow = add_material(stage, "/Looks/Glow", (0.0, 0.0, 0.0), emissive=(8.0, 6.0, 4.0))
    floor = add_mesh(stage, "/Floor", [(-8, -1, -8), (-8, -1, 8), (8, -1, 8), (8, -1, -8)], [4], [0, 1, 2, 3])
    floor.CreateDisplayColorAttr([Gf.Vec3f(0.6, 0.6, 0.6)])
    pi = UsdGeom.PointInstancer.Define(stage, "/PI")
    h = 0.5
    pts = [(x, y, z) for z in (-h, h) for y in (-h, h) for x in (-h, h)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    mesh = add_mesh(stage, "/PI/Protos/Box", pts, [4] * 6, [i for q in quads for i in q], mat)
    st = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9)] * 6
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.faceVarying).Set([Gf.Vec2f(*v) for v in st])
    mesh.CreateNormalsAttr([Gf.Vec3f(*(np.array(pts[i]) / np.linalg.norm(pts[i]))) for q in quads for i in q])
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    add_mesh(stage, "/PI/Protos/Lamp", [(-0.4, 0, -0.4), (0.4, 0, -0.4), (0.4, 0, 0.4), (-0.4, 0, 0.4)], [4],
             [0, 1, 2, 3], glow)   # faces -y
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/PI/Protos/Box"), Sdf.Path("/PI/Protos/Lamp")])
    pi.CreateProtoIndicesAttr([0, 0, 0, 0, 1, 1])
    pi.CreatePositionsAttr([Gf.Vec3f(-2, -0.4, -6), Gf.Vec3f(0, -0.3, -7), Gf.Vec3f(2, -0.5, -6),
                            Gf.Vec3f(0.5, 0.2, -4.5), Gf.Vec3f(-1, 2, -6), Gf.Vec3f(1.5, 2.2, -6.5)])
    pi.CreateScalesAttr([Gf.Vec3f(1, 1, 1), Gf.Vec3f(1.5, 0.6, 1), Gf.Vec3f(-1, 1, 1), Gf.Vec3f(0.5, 0.5, 0.5),
                         Gf.Vec3f(1, 1, 1), Gf.Vec3f(-1.2, 1, 1)])
    q = lambda deg, axis: Gf.Quath(math.cos(math.radians(deg) / 2), *(math.sin(math.radians(deg) / 2) * a for a in axis))
    pi.CreateOrientationsAttr([q(30, (0, 1, 0)), q(20, (1, 0, 0)), q(-40, (0, 1, 0)), q(45, (0, 0, 1)),
                               q(0, (0, 1, 0)), q(25, (0, 1, 0))])
    light = UsdLux.SphereLight.Define(stage, "/Bulb")
    light.AddTranslateOp().Set(Gf.Vec3d(3, 4, -3))
    light.CreateRadiusAttr(0.3)
    light.CreateIntensityAttr(30.0)
    cam = add_camera(stage, "/Cam", (0, 1, 0), focal=20.0, haperture=36.0, vaperture=24.0)
    cam.AddRotateXOp().Set(-12.0)
    add_render_settings(stage, cam, (48, 32))
    return save(stage)


def image_mean_z(a, va, b, vb, spp):
    """Per channel: the image-wide mean of a minus that of b, and the standard error of the
    difference, from each render's per-pixel sample variance (the renders independent)."""
    n = a.shape[0] * a.shape[1]
    diff = a[..., :3].mean(axis=(0, 1)) - b[..., :3].mean(axis=(0, 1))
    se = np.sqrt((va.sum(axis=(0, 1)) + vb.sum(axis=(0, 1))) / spp / n ** 2)
    return diff, se


def assert_image_means_agree(a, va, b, vb, spp):
    """The image means of two independent renders agree per channel (normal z, Bonferroni
    over 3 channels at 1e-3); the comparison detects 2 % (asserted), and b scaled by 1.02
    fails it (the negative control)."""
    from scipy import stats

    limit = stats.norm.isf(1e-3 / (2 * 3))
    diff, se = image_mean_z(a, va, b, vb, spp)
    assert (np.abs(diff) < limit * se).all(), (diff, se)
    detectable = limit * se / a[..., :3].mean(axis=(0, 1))
    assert (detectable < 0.02).all(), detectable
    diff2, se2 = image_mean_z(a, va, b * np.float32(1.02), vb * np.float32(1.02 ** 2), spp)
    assert (np.abs(diff2) > limit * se2).any(), "an instanced image 2 % too bright passes"


def test_point_instancer_renders_the_same_as_flattened_and_auto_picks_instances(tmp_path):
    """Instanced and flattened renders of the same scene, with independent seeds, agree per
    channel on the image mean (normal z, Bonferroni over 3 channels at 1e-3) and on every
    8 x 8 block (Bonferroni over blocks x channels). Power: the image-mean comparison detects
    a relative error of 2 % (asserted; measured 1.2-1.5 % per channel at 2048 spp), and the negative control, the
    instanced image scaled by 1.02, must fail it. The light and bdpt integrators are compared
    the same way over 16 seeds each with Welch's t (measured power: light 1.1 %, bdpt 1.1 %), each with the same
    2 % negative control."""
    from scipy import stats
    path = _instancer_scene(tmp_path)
    flat = load_scene(path, instancing="flatten")
    auto = load_scene(path)  # the default
    assert flat.num_instances == 0 and auto.num_instances == 6
    assert auto.num_triangles == flat.num_triangles
    assert auto.num_stored_triangles < flat.num_stored_triangles
    assert auto.num_emitters == flat.num_emitters   # each lamp instance is a light
    spp = 2048
    a, va = flat.render_tile(0, 0, 48, 32, spp=spp, seed=3, return_variance=True)
    b, vb = auto.render_tile(0, 0, 48, 32, spp=spp, seed=1003, return_variance=True)
    assert a[..., :3].mean() > 0.05
    assert_image_means_agree(a, va, b, vb, spp)
    blocks = 3 * (48 // 8) * (32 // 8)
    assert block_z(a, va, b, vb, spp) < stats.norm.isf(1e-3 / (2 * blocks))
    for integrator, ispp in (("light", 128), ("bdpt", 32)):
        totals = {}
        for name, scene, base in (("flat", flat, 5), ("auto", auto, 505)):
            totals[name] = []
            for k in range(16):
                splats = np.zeros((32, 48, 3), np.int64)
                img = scene.render_tile(0, 0, 48, 32, spp=ispp, seed=base + k, integrator=integrator, splats=splats)
                # splats are fixed point (2^24); the merge divides them by the light paths traced
                totals[name].append(img[..., :3].mean() + splats.sum() / 2 ** 24 / (48 * 32 * ispp) / 3)
        ta, tb = np.array(totals["flat"]), np.array(totals["auto"])
        sa, sb = ta.var(ddof=1) / len(ta), tb.var(ddof=1) / len(tb)
        df = (sa + sb) ** 2 / (sa ** 2 / (len(ta) - 1) + sb ** 2 / (len(tb) - 1))
        t_limit = stats.t.isf(1e-3 / (2 * 2), df)
        assert abs(ta.mean() - tb.mean()) < t_limit * math.sqrt(sa + sb), (integrator, ta.mean(), tb.mean())
        assert t_limit * math.sqrt(sa + sb) / ta.mean() < 0.02, (integrator, t_limit * math.sqrt(sa + sb) / ta.mean())
        # Negative control: auto 2 % too bright fails the same test.
        sb2 = sb * 1.02 ** 2
        df2 = (sa + sb2) ** 2 / (sa ** 2 / (len(ta) - 1) + sb2 ** 2 / (len(tb) - 1))
        assert abs(ta.mean() - 1.02 * tb.mean()) > stats.t.isf(1e-3 / 4, df2) * math.sqrt(sa + sb2), integrator


def test_instanced_blob_round_trip_renders_identically(tmp_path):
    path = _instancer_scene(tmp_path)
    direct = load_scene(path)
    blob_scene = scene_from_blob(translate_to_blob(path))  # the farm's path, default instancing
    assert blob_scene.num_instances == 6
    a = direct.render_tile(0, 0, 48, 32, spp=8, seed=1)
    b = blob_scene.render_tile(0, 0, 48, 32, spp=8, seed=1)
    np.testing.assert_array_equal(a, b)


def test_auto_flattens_when_lights_hide_inside_native_instances(tmp_path):
    asset = new_stage(tmp_path / "asset.usda")
    root = UsdGeom.Xform.Define(asset, "/Asset")
    add_mesh(asset, "/Asset/Geo", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    UsdLux.SphereLight.Define(asset, "/Asset/Bulb").CreateRadiusAttr(0.1)
    asset.SetDefaultPrim(root.GetPrim())
    save(asset)
    stage = new_stage(tmp_path / "scene.usda")
    for k in range(2):
        x = UsdGeom.Xform.Define(stage, f"/I{k}")
        x.AddTranslateOp().Set(Gf.Vec3d(5 * k, 0, 0))
        x.GetPrim().GetReferences().AddReference("./asset.usda")
        x.GetPrim().SetInstanceable(True)
    path = save(stage)
    data = translate_stage(path, instancing="auto")
    assert len(data.instances) == 0 and len(data.sphere_lights) == 2
    assert any("flattened" in w for w in data.warnings)


@pytest.mark.shared_scenes
def test_real_instancing_scene_instances_equal_flattened(tmp_path):
    import shutil
    work = tmp_path / "vfx"
    shutil.copytree(SCENES / "usdwg_intent_vfx_instancing", work)
    root = work / "scenes" / "shot.usda"
    root.write_text('#usda 1.0\n(subLayers = [@./teapotScene_camera.usd@, @./teapotScene_layout.usd@])\n')
    # Level 0: the teapot's cage; refined, 1000 flattened copies pass the triangle limit.
    kw = dict(frame=120, root=str(work), default_light=True, subdivision_level=0)
    flat = load_scene(root, instancing="flatten", **kw)
    inst = load_scene(root, **kw)
    assert inst.num_instances == 1000 and inst.num_stored_triangles == 2472
    assert inst.num_triangles == flat.num_triangles == 1000 * 2472
    # Independent seeds; the image mean per channel (normal z, Bonferroni over 3 channels at
    # 1e-3) must detect 2 % (asserted) and flag the instanced image scaled by 1.02; every
    # 8 x 8 block must agree too (Bonferroni over blocks x channels). Measured power: 0.3-0.8 %.
    from scipy import stats
    spp = 16
    a, va = flat.render_tile(0, 0, 64, 40, width=64, height=40, spp=spp, seed=2, return_variance=True)
    b, vb = inst.render_tile(0, 0, 64, 40, width=64, height=40, spp=spp, seed=1002, return_variance=True)
    assert a[..., :3].mean() > 0.05
    assert_image_means_agree(a, va, b, vb, spp)
    assert block_z(a, va, b, vb, spp) < stats.norm.isf(1e-3 / (2 * 3 * (64 // 8) * (40 // 8)))


def test_normal_map_without_the_spec_scale_and_bias_warns(tmp_path):
    write_image(tmp_path / "n.exr", np.tile(np.array([0.5, 0.5, 1.0], np.float32), (2, 2, 1)))
    bare = textured_floor(tmp_path, "bare", "./n.exr", input_name="normal")
    assert any("normal maps without scale" in w for w in load_scene(bare).warnings)
    proper = textured_floor(tmp_path, "proper", "./n.exr", input_name="normal", tex_inputs={
        "scale": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(2, 2, 2, 1)),
        "bias": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(-1, -1, -1, 0))})
    assert not any("normal maps without scale" in w for w in load_scene(proper).warnings)


def test_blob_size_is_the_blob_but_its_header(tmp_path):
    """scene_blob.blob_size (the pre-flight's translated-size limit) is the blob's length
    less its 16-byte preamble and JSON header, 64-byte aligned (the format in scene_blob's
    docstring), for a scene with UDIM texture files and one with prototypes."""
    import struct
    from tessera_renderer.scene_blob import blob_size, scene_data_to_blob

    write_image(tmp_path / "u.1001.png", np.full((4, 4, 3), 40, np.uint8))
    write_image(tmp_path / "u.1002.png", np.full((4, 4, 3), 200, np.uint8))
    for path in (textured_floor(tmp_path, "udim", "./u.<UDIM>.png", center_st=(1.5, 0.5)),
                 _instancer_scene(tmp_path)):
        data = translate_stage(str(path), instancing="auto")
        blob = scene_data_to_blob(data)
        header = struct.unpack("<I", blob[12:16])[0]
        start = -(-(16 + header) // 64) * 64
        assert blob_size(data) == len(blob) - start > 0
