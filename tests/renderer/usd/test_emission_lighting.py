"""Issue 43: whether a stage is lit is decided by its UsdLux lights; material emission lights
a light-less stage only when its measured power reaches a share of what the default
lighting gives (docs/scene-translation.md). Emission that is provably zero (a texture of
black texels, a fallback of black) counts as none.

The files are written as the converters write them: Apple's converter connects every
UsdPreviewSurface input to a UsdUVTexture, black emission included; glTF converters write
emissiveColor as a UsdUVTexture of the emissive map with the emissiveFactor as its scale."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from tessera_renderer import load_scene
from tessera_renderer.usd import NO_LIGHT_WARNING, translate_stage
from tessera_renderer.usd.emission import EMISSION_LIGHTS_FRACTION
from usd_fixtures import add_material, new_stage


def _write_png(path, pixels: np.ndarray) -> str:
    import OpenImageIO as oiio

    assert oiio.ImageBuf(np.ascontiguousarray(pixels)).write(str(path))
    return str(path)


def _grid(stage, path, n, half, material, albedo=None):
    """An n x n grid of quads over [-half, half]^2 at z = 0 facing +z, with st over [0, 1]
    (faceVarying, as converters write it): 2 n^2 triangles."""
    xs = np.linspace(-half, half, n + 1)
    pts = [Gf.Vec3f(float(x), float(y), 0.0) for y in xs for x in xs]
    counts, idx, st = [], [], []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            quad = [a, a + 1, a + n + 2, a + n + 1]
            counts.append(4)
            idx += quad
            st += [Gf.Vec2f((q % (n + 1)) / n, (q // (n + 1)) / n) for q in quad]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(idx)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.faceVarying).Set(st)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _emission_texture(stage, mat_path, file=None, fallback=None, scale=None, srgb=True):
    """emissiveColor <- UsdUVTexture (reading st) as the converters write it."""
    mat = add_material(stage, mat_path, (0.5, 0.5, 0.5))
    reader = UsdShade.Shader.Define(stage, mat_path + "/st")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, mat_path + "/emissive_texture")
    tex.CreateIdAttr("UsdUVTexture")
    if file is not None:
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    if fallback is not None:
        tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*fallback))
    if scale is not None:
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
    if srgb:
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface = UsdShade.Shader(stage.GetPrimAtPath(mat_path + "/Surface"))
    surface.GetInput("emissiveColor").ConnectToSource(tex.ConnectableAPI(), "rgb")
    return mat


def _lambertian(stage, mat_path):
    """No specular lobe: the surface renders as Lambert (docs/materials.md)."""
    surf = UsdShade.Shader(stage.GetPrimAtPath(mat_path + "/Surface"))
    surf.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    surf.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))


def _save(stage) -> str:
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


def _light_lines(warnings):
    return [w for w in warnings if "light" in w]


# -- 1. emission that is provably zero does not make a stage lit ---------------------------
@pytest.mark.parametrize("case", ["no file", "missing file", "black image", "zero scale"])
def test_black_emission_texture_leaves_the_asset_lightless(tmp_path, case):
    """Each variant emits nothing anywhere; every one used to be judged emissive (the
    black image and the zero scale by the old rule "an emissiveColor texture emits")."""
    black = _write_png(tmp_path / "black.png", np.zeros((8, 8, 3), np.uint8))
    white = _write_png(tmp_path / "white.png", np.full((8, 8, 3), 255, np.uint8))
    file, scale = {"no file": (None, None), "missing file": ("./gone.png", None),
                   "black image": ("./black.png", None), "zero scale": ("./white.png", (0, 0, 0, 1))}[case]
    stage = new_stage(tmp_path / "apple.usda")
    _grid(stage, "/Asset/Mesh", 4, 1.0, _emission_texture(stage, "/Asset/Looks/M", file, (0, 0, 0, 1), scale))
    data = translate_stage(_save(stage))
    assert data.default_lights is not None
    assert _light_lines(data.warnings) == [NO_LIGHT_WARNING], data.warnings  # no emission line: it is zero
    del black, white


def test_a_black_emission_asset_renders_by_the_default_lighting(tmp_path):
    """The Apple-converter asset of issue 43 renders as the default lighting's closed form
    (a Lambertian grey quad: a (0.5 + 0.8 cos theta_key)), not black; a 2 % error fails."""
    _write_png(tmp_path / "black.png", np.zeros((8, 8, 3), np.uint8))
    stage = new_stage(tmp_path / "apple.usda")
    mat = _emission_texture(stage, "/Asset/Looks/M", "./black.png", (0, 0, 0, 1))
    _lambertian(stage, "/Asset/Looks/M")
    _grid(stage, "/Asset/Mesh", 2, 1.0, mat)
    scene = load_scene(_save(stage))
    c = scene.data.camera
    toward = -np.array(c.forward) + 0.8 * np.array(c.up) - 0.6 * np.array(c.right)
    toward /= np.linalg.norm(toward)
    expected = 0.5 * (0.5 + 0.8 * max(float(toward[2]), 0.0))
    w = h = 64
    spp = 256
    rgba, aov = scene.render_tile(0, 0, w, h, width=w, height=h, spp=spp, seed=3, aovs=("albedo", "variance"))
    mask = np.abs(aov["albedo"][:, :, 0] - 0.5) < 1e-4
    assert mask.sum() >= 200
    mean = float(rgba[:, :, 0][mask].mean())
    se = math.sqrt(float((aov["variance"][:, :, 0][mask] / spp).sum())) / mask.sum()
    assert 0.02 * expected > 8 * se, "the check must detect a 2 % error"
    assert abs(mean - expected) < 4 * se + 1e-6, (mean, se, expected)
    assert abs(mean - 1.02 * expected) > 4 * se  # negative control


# -- 2. faint textured emission: measured power against the default lighting ---------------
N = 32  # grid quads per side; the emissive map has one texel per quad
PATCH = 2  # the map's lit patch, PATCH x PATCH texels of white


def _helmet(tmp_path, scale=1.0, light=False, name="helmet.usda"):
    """A glTF-converted asset: 2 N^2 triangles all bound to one material whose emissive
    map is black but for a PATCH^2 white patch; emissiveFactor `scale`."""
    img = np.zeros((N, N, 3), np.uint8)
    img[10:10 + PATCH, 20:20 + PATCH] = 255
    _write_png(tmp_path / "emissive.png", img)
    stage = new_stage(tmp_path / name)
    mat = _emission_texture(stage, "/Helmet/Looks/M", "./emissive.png", scale=(scale, scale, scale, 1.0))
    _grid(stage, "/Helmet/Mesh", N, 1.0, mat)
    if light:
        UsdLux.DistantLight.Define(stage, "/Sun").CreateIntensityAttr(1.0)
    return _save(stage)


def _note_power(warnings) -> tuple[float, float]:
    line = next(w for w in warnings if "only emission" in w)
    power, reference = (float(x) for x in re.findall(r"power ([\d.e+-]+)\).*gives it \(([\d.e+-]+)\)", line)[0])
    return power, reference


def test_faint_emissive_map_gets_default_lighting_and_its_power_is_measured(tmp_path):
    data = translate_stage(_helmet(tmp_path))
    assert data.default_lights is not None
    lines = _light_lines(data.warnings)
    assert lines[0] == NO_LIGHT_WARNING and len(lines) == 2
    assert f"{2 * N * N} triangles of emissive materials" in lines[1]
    assert "default lighting lights the rest" in lines[1]
    unlit = load_scene(_helmet(tmp_path, name="unlit.usda"), default_light=False)
    assert [w for w in unlit.warnings if "only emission" in w][0].endswith(
        "with default lighting off, the emission alone lights it (dimly)")
    power, reference = _note_power(data.warnings)
    # Closed forms from the authored file: the quad (area 4) emits pi * 4 * (white texel
    # share); the default lighting gives pi 0.5 * 4 pi R^2 + 0.8 pi * pi R^2, R = sqrt 2.
    assert power == pytest.approx(math.pi * 4.0 * PATCH ** 2 / N ** 2, rel=1e-3)
    assert reference == pytest.approx(math.pi ** 2 * 2.0 * (2.0 + 0.8), rel=1e-3)


def test_emission_at_the_threshold_lights_the_stage(tmp_path):
    """The rule's edge from both sides: the factor that puts the power at 1.05x the
    threshold lights the stage, the one at 0.95x does not."""
    reference = math.pi ** 2 * 2.0 * 2.8
    unit_power = math.pi * 4.0 * PATCH ** 2 / N ** 2
    at = EMISSION_LIGHTS_FRACTION * reference / unit_power
    above = translate_stage(_helmet(tmp_path, scale=1.05 * at, name="above.usda"))
    below = translate_stage(_helmet(tmp_path, scale=0.95 * at, name="below.usda"))
    assert above.default_lights is None and not _light_lines(above.warnings)
    assert below.default_lights is not None and len(_light_lines(below.warnings)) == 2


def test_a_usdlux_light_makes_a_stage_lit_whatever_its_emission(tmp_path):
    data = translate_stage(_helmet(tmp_path, light=True))
    assert data.default_lights is None and not _light_lines(data.warnings)


# -- 2b. the dark parts of an emissive map make no emitters ---------------------------------
def _patch_reach() -> int:
    """Triangles whose bilinear lookups can read a patch texel, counted from the layout
    alone: a grid quad i reads texel columns i - 1 .. i + 1 (texel centres at half
    integers), and rows N - j - 2 .. N - j (rows run top down)."""
    rows, cols = range(10, 10 + PATCH), range(20, 20 + PATCH)
    quads = sum(1 for j in range(N) for i in range(N)
                if any(i - 1 <= c <= i + 1 for c in cols) and any(N - j - 2 <= r <= N - j for r in rows))
    return 2 * quads


def test_dark_parts_of_an_emissive_map_make_no_emitters(tmp_path):
    """Before: every triangle of the material was an emitter (2 N^2 = 2048); now only
    those that can read a lit texel (32). Negative control: the same map with its black
    texels at the smallest 8-bit value lit makes every triangle an emitter again."""
    scene = load_scene(_helmet(tmp_path), default_light=False)
    assert _patch_reach() == 32
    assert scene.num_emitters == _patch_reach()
    img = np.full((N, N, 3), 1, np.uint8)
    img[10:10 + PATCH, 20:20 + PATCH] = 255
    path = _helmet(tmp_path, name="faint.usda")
    _write_png(tmp_path / "emissive.png", img)
    assert load_scene(path, default_light=False).num_emitters == 2 * N * N


@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror"])
def test_a_lit_column_at_the_edge_reaches_across_as_the_wrap_mode_reads(tmp_path, wrap):
    """The map's first texel column lit: every quad of columns 0 and 1 reads it, and the
    last column's quads read it across the edge under repeat (texel N wraps to 0) but not
    under clamp or mirror (texel N is N - 1). Counted from the layout: 2 N (2 or 3)."""
    img = np.zeros((N, N, 3), np.uint8)
    img[:, 0] = 255
    _write_png(tmp_path / "edge.png", img)
    stage = new_stage(tmp_path / "edge.usda")
    mat = _emission_texture(stage, "/A/Looks/M", "./edge.png")
    tex = UsdShade.Shader(stage.GetPrimAtPath("/A/Looks/M/emissive_texture"))
    for name in ("wrapS", "wrapT"):
        tex.CreateInput(name, Sdf.ValueTypeNames.Token).Set(wrap)
    _grid(stage, "/A/Mesh", N, 1.0, mat)
    scene = load_scene(_save(stage), default_light=False)
    assert scene.num_emitters == 2 * N * (3 if wrap == "repeat" else 2)


def test_the_lit_patch_still_shows_its_authored_radiance(tmp_path):
    """Camera rays see the patch's emission, the authored white texel (sRGB 1 -> 1.0 x
    emissiveFactor 3), at pixels wholly inside it; the black rest shows nothing."""
    img = np.zeros((N, N, 3), np.uint8)
    img[8:24, 8:24] = 255  # a patch big enough for whole pixels
    stage = new_stage(tmp_path / "big.usda")
    _write_png(tmp_path / "big.png", img)
    mat = _emission_texture(stage, "/Helmet/Looks/M", "./big.png", scale=(3.0, 3.0, 3.0, 1.0))
    UsdShade.Shader(stage.GetPrimAtPath("/Helmet/Looks/M/Surface")).GetInput("diffuseColor").Set(Gf.Vec3f(0, 0, 0))
    _lambertian(stage, "/Helmet/Looks/M")
    _grid(stage, "/Helmet/Mesh", N, 1.0, mat)
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 4))
    cam.CreateFocalLengthAttr(50.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(36.0)
    scene = load_scene(_save(stage), default_light=False)
    w = 64
    rgba = scene.render_tile(0, 0, w, w, width=w, height=w, spp=4)
    # The quad spans [-1, 1] at distance 4: half-width 1 / (4 tan(half fov)) of the frame,
    # tan(half fov) = 18 / 50; the patch is its middle half.
    half = 0.5 * w * 1.0 / (4 * 18 / 50)
    lo, hi = int(w / 2 - half / 2) + 2, int(w / 2 + half / 2) - 2
    inner = rgba[lo:hi, lo:hi, :3]
    assert inner.size > 0 and np.allclose(inner, 3.0, rtol=1e-3)
    outer = rgba[int(w / 2 - half) + 1:int(w / 2 - half / 2) - 2, int(w / 2 - half) + 1:int(w / 2 + half) - 1, :3]
    assert outer.size > 0 and outer.max() == 0.0
    assert scene.num_emitters < 2 * N * N


def test_the_bundled_cornell_box_keeps_its_emissive_ceiling_light(cornell_path):
    """The example's light is an emissive quad (no UsdLux light): 8.4 % of the default
    lighting's power, above the threshold, so it stays the scene's only light."""
    data = translate_stage(str(cornell_path))
    assert data.default_lights is None and not _light_lines(data.warnings)


@pytest.mark.parametrize("instancing", ["auto", "flatten"])
def test_instanced_emitters_count_each_instance_with_its_scale(tmp_path, instancing):
    """A PointInstancer of four unit quads emitting 0.1, scaled 2: pi x 4 x (2 x 2) x 0.1
    whether the instances stay Embree instances (area x |det|^(2/3)) or are flattened."""
    stage = new_stage(tmp_path / "inst.usda")
    glow = add_material(stage, "/Looks/G", (0, 0, 0), emissive=(0.1, 0.1, 0.1))
    points = UsdGeom.PointInstancer.Define(stage, "/P")
    quad = UsdGeom.Mesh.Define(stage, "/P/Protos/Q")
    quad.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(quad.GetPrim()).Bind(glow)
    points.CreatePrototypesRel().SetTargets([quad.GetPath()])
    points.CreateProtoIndicesAttr([0] * 4)
    points.CreatePositionsAttr([Gf.Vec3f(2 * i, 0, 0) for i in range(4)])
    points.CreateScalesAttr([Gf.Vec3f(2, 2, 2)] * 4)
    data = translate_stage(_save(stage), instancing=instancing)
    assert (len(data.instances) == 4) is (instancing == "auto")
    power, _ = _note_power(data.warnings)
    assert power == pytest.approx(math.pi * 16 * 0.1, rel=1e-3)
