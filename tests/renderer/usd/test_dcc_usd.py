"""USD as DCC tools and asset libraries write it (issue 11): light-less assets, UV sets by
name, packages inside packages, variants, camera framing, partial opacity, skinning.

Files are either real ones from ../shared/scenes or small stages written here that model
what the named exporter writes; every image check is one a black or grey image fails."""
from __future__ import annotations

import re

import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from conftest import SHARED_SCENES, require_shared_scenes
from tessera_renderer import load_scene
from tessera_renderer.scene_blob import scene_from_blob, translate_to_blob
from tessera_renderer.usd import translate_stage
from usd_fixtures import add_material, add_mesh, add_quad, lightless_quad, new_stage, save_stage, write_four_texel_png

SCENES = SHARED_SCENES


def _mean_and_error(scene, w, h, spp, seed, albedo):
    """Mean of the red channel over the pixels wholly covered by a surface of the given
    albedo (from the albedo AOV) and its standard error (from the per-pixel sample
    variance)."""
    rgba, aov = scene.render_tile(0, 0, w, h, width=w, height=h, spp=spp, seed=seed,
                                  aovs=("albedo", "variance"))
    mask = np.abs(aov["albedo"][:, :, 0] - albedo) < 1e-4
    assert mask.sum() >= 50, "the surface must cover the frame's centre"
    px = rgba[:, :, 0][mask]
    v = aov["variance"][:, :, 0][mask] / spp
    return float(px.mean()), float(math.sqrt(v.sum()) / len(px))


def _agrees(mean, se, expected):
    return abs(mean - expected) < 4.0 * se + 1e-6 * expected


# -- 1. light-less stages get default lighting ------------------------------------------


def test_lightless_stage_is_lit_by_a_dome_and_a_camera_key_light(tmp_path):
    path = lightless_quad(tmp_path)
    scene = load_scene(path)
    light_lines = [w for w in scene.warnings if "light" in w]
    assert len(light_lines) == 1 and "default lighting" in light_lines[0]
    # Closed form for a Lambertian quad (albedo a) facing the camera, open to the sky:
    # dome radiance 0.5 gives a * 0.5; the key light (illuminance 0.8 pi, from the
    # documented direction -forward + 0.8 up - 0.6 right) adds a * 0.8 * cos(theta).
    c = scene.data.camera
    toward = -np.array(c.forward) + 0.8 * np.array(c.up) - 0.6 * np.array(c.right)
    toward /= np.linalg.norm(toward)
    normal = np.array([0.0, 0.0, 1.0])
    expected = 0.5 * (0.5 + 0.8 * max(float(normal @ toward), 0.0))
    mean, se = _mean_and_error(scene, 96, 96, 256, 1, 0.5)
    assert 0.02 * expected > 8 * se, "the check must detect a 2 % error"
    assert _agrees(mean, se, expected), (mean, se, expected)
    assert not _agrees(mean, se, expected * 1.02)  # negative control: 2 % off fails


def test_default_lighting_can_be_switched_off_and_then_says_black(tmp_path):
    path = lightless_quad(tmp_path)
    dark = load_scene(path, default_light=False)
    assert [w for w in dark.warnings if "light" in w] == [
        "the scene has no lights and default lighting is off: it renders black"]
    assert dark.render_tile(0, 0, 16, 16, width=16, height=16, spp=4)[..., :3].max() == 0.0
    # The blob carries the default lights unapplied: one translation serves both renders.
    blob = translate_to_blob(path)
    lit = scene_from_blob(blob)
    unlit = scene_from_blob(blob, default_light=False)
    assert lit.render_tile(0, 0, 16, 16, width=16, height=16, spp=4)[8, 8, 0] > 0.2
    assert unlit.render_tile(0, 0, 16, 16, width=16, height=16, spp=4)[..., :3].max() == 0.0


def test_cli_no_default_light(tmp_path):
    import OpenImageIO as oiio

    from tessera_cli.cli import main

    path = lightless_quad(tmp_path)
    for flag, lit in (([], True), (["--no-default-light"], False)):
        out = tmp_path / f"o{len(flag)}.exr"
        assert main(["render", path, "--res", "16x16", "--spp", "2", "-q", "-o", str(out)] + flag) == 0
        px = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)
        assert (float(px[8, 8, 0]) > 0.2) if lit else (float(px[..., :3].max()) == 0.0)


def test_job_setting_default_light():
    from tessera_base.protocol import RenderSettings

    assert RenderSettings(width=8, height=8).default_light is True
    assert RenderSettings.model_validate_json(
        RenderSettings(width=8, height=8, default_light=False).model_dump_json()).default_light is False


def test_emissive_only_stage_is_not_lightless(tmp_path):
    import OpenImageIO as oiio

    stage = new_stage(tmp_path / "emit.usda")
    add_quad(stage, material=add_material(stage, "/Looks/E", (0, 0, 0), emissive=(2.0, 2.0, 2.0)))
    data = translate_stage(save_stage(stage))
    assert data.default_lights is None and not any("no lights" in w for w in data.warnings)
    # Emission from a texture (constant emissiveColor is only the fallback, 0 here).
    oiio.ImageBuf(np.full((2, 2, 3), 255, np.uint8)).write(str(tmp_path / "e.png"))
    stage = new_stage(tmp_path / "emit_tex.usda")
    mat = add_material(stage, "/Looks/E", (0, 0, 0))
    tex = UsdShade.Shader.Define(stage, "/Looks/E/T")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./e.png")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/E/Surface")).GetInput("emissiveColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    add_quad(stage, material=mat)
    scene = load_scene(save_stage(stage))
    assert scene.data.default_lights is None and scene.data.dome_light is None
    assert not any("no lights" in w for w in scene.warnings)
    # The quad emits the texture (white, radiance 1): the image shows it, not black.
    assert scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=4)[8, 8, 0] == pytest.approx(1.0, abs=0.02)


def test_preflight_reports_the_unlit_warnings_for_a_lightless_stage(tmp_path, capsys):
    import json

    from tessera_renderer import inspect

    assert inspect.main([lightless_quad(tmp_path)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert any("default lighting" in w for w in info["warnings"])
    assert "the scene has no lights and default lighting is off: it renders black" in info["unlit_warnings"]


# -- 2. UV sets by name ------------------------------------------------------------------
def _pixel_of(scene, world_point, w, h):
    """(row, column) of the pixel a world point projects to (pinhole camera)."""
    c = scene.data.camera
    p = np.asarray(world_point, float) - np.asarray(scene.data.world_offset) - np.asarray(c.origin)
    tan_w, tan_h = c.tan_half_angles(w, h)
    depth = p @ np.asarray(c.forward)
    x = (0.5 + 0.5 * (p @ np.asarray(c.right)) / depth / tan_w) * w
    y = (0.5 - 0.5 * (p @ np.asarray(c.up)) / depth / tan_h) * h
    return int(y), int(x)


def _emissive_textured_material(stage, path, uv_name, via_interface):
    """What Apple's usdz converter writes: UsdUVTexture <- UsdPrimvarReader_float2 whose
    varname is connected to the material's interface input frame:stPrimvarName."""
    mat = add_material(stage, path, (0, 0, 0))
    reader = UsdShade.Shader.Define(stage, path + "/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    var = reader.CreateInput("varname", Sdf.ValueTypeNames.Token)
    if via_interface:
        iface = mat.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.Token)
        iface.Set(uv_name)
        var.ConnectToSource(iface)
    else:
        var.Set(uv_name)
    tex = UsdShade.Shader.Define(stage, path + "/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./four.png")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    UsdShade.Shader(stage.GetPrimAtPath(path + "/Surface")).GetInput("emissiveColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    return mat


def test_uv_sets_by_name_per_subset_through_interface_inputs(tmp_path):
    write_four_texel_png(tmp_path / "four.png")
    stage = new_stage(tmp_path / "uvsets.usda")
    # Three unit quads in a row, one mesh; each face is a GeomSubset with its own material.
    pts = [(x + dx, y, 0) for x in (-3, -1, 1) for dx, y in ((0, -1), (2, -1), (2, 1), (0, 1))]
    mesh = add_mesh(stage, "/Mesh", pts, [4, 4, 4], list(range(12)))
    api = UsdGeom.PrimvarsAPI(mesh)
    for name, st in (("Texture_uv", (0.25, 0.25)), ("st1", (0.75, 0.75)), ("st", (0.75, 0.25))):
        api.CreatePrimvar(name, Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
            [Gf.Vec2f(*st)] * 12)
    mats = [_emissive_textured_material(stage, "/Looks/A", "Texture_uv", via_interface=True),
            _emissive_textured_material(stage, "/Looks/B", "st1", via_interface=False),
            _emissive_textured_material(stage, "/Looks/C", "Missing_uv", via_interface=True)]
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for face, mat in enumerate(mats):
        subset = binding.CreateMaterialBindSubset(f"face{face}", [face])
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
    scene = load_scene(save_stage(stage))
    assert any("'Missing_uv'" in w and "default set" in w for w in scene.warnings)
    w, h = 96, 48
    img = scene.render_tile(0, 0, w, h, width=w, height=h, spp=4)
    expected = {-2: (0, 0, 1), 0: (0, 1, 0), 2: (1, 1, 1)}  # blue (Texture_uv), green (st1), white (st)
    for x, rgb in expected.items():
        row, col = _pixel_of(scene, (x, 0, 0), w, h)
        np.testing.assert_allclose(img[row, col, :3], rgb, atol=0.02, err_msg=f"face at x={x}")


# -- 3. packages inside packages ---------------------------------------------------------
def _red_asset_layer(folder: Path, texture="./tex.png") -> Path:
    """An asset layer as usdz exporters write one: a quad emitting its texture."""
    import OpenImageIO as oiio

    folder.mkdir(parents=True, exist_ok=True)
    oiio.ImageBuf(np.full((2, 2, 3), (255, 0, 0), np.uint8)).write(str(folder / "tex.png"))
    stage = new_stage(folder / "asset.usda")
    mat = add_material(stage, "/Asset/Looks/M", (0, 0, 0))
    tex = UsdShade.Shader.Define(stage, "/Asset/Looks/M/T")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    UsdShade.Shader(stage.GetPrimAtPath("/Asset/Looks/M/Surface")).GetInput("emissiveColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    add_quad(stage, "/Asset/Quad", material=mat)
    stage.SetDefaultPrim(stage.GetPrimAtPath("/Asset"))
    save_stage(stage)
    return folder / "asset.usda"


def _usdz(path: Path, members: list[tuple[Path, str]]) -> Path:
    writer = Sdf.ZipFileWriter.CreateNew(str(path))
    for src, name in members:
        writer.AddFile(str(src), name)
    writer.Save()
    return path


def _set_referencing(path: Path, asset: str) -> str:
    stage = new_stage(path)
    stage.DefinePrim("/Set/A").GetReferences().AddReference(asset)
    stage.SetDefaultPrim(stage.GetPrimAtPath("/Set"))
    return save_stage(stage)


def _centre_is_red(scene):
    img = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=2)
    np.testing.assert_allclose(img[8, 8, :3], (1.0, 0.0, 0.0), atol=0.01)


def test_textures_of_a_usdz_referenced_from_a_layer(tmp_path):
    layer = _red_asset_layer(tmp_path / "src")
    _usdz(tmp_path / "asset.usdz", [(layer, "asset.usda"), (layer.parent / "tex.png", "tex.png")])
    path = _set_referencing(tmp_path / "set.usda", "./asset.usdz")
    # Unlit: the red emission alone (1.0) is under the threshold that makes emission
    # lighting (docs/scene-translation.md), and only the texture is checked here.
    scene = load_scene(path, default_light=False)
    assert not any("missing" in w for w in scene.warnings), scene.warnings
    _centre_is_red(scene)
    # The same set as a farm bundle (.zip of set + package) through the blob.
    bundle = tmp_path / "bundle.zip"
    with zipfile.ZipFile(bundle, "w") as zf:
        zf.write(path, "set.usda")
        zf.write(tmp_path / "asset.usdz", "asset.usdz")
    _centre_is_red(scene_from_blob(translate_to_blob(bundle), default_light=False))


def test_textures_of_a_package_nested_in_a_package(tmp_path):
    layer = _red_asset_layer(tmp_path / "src")
    inner = _usdz(tmp_path / "src" / "inner.usdz", [(layer, "asset.usda"), (layer.parent / "tex.png", "tex.png")])
    outer_layer = tmp_path / "src" / "outer.usda"
    _set_referencing(outer_layer, "./inner.usdz")
    _usdz(tmp_path / "outer.usdz", [(outer_layer, "outer.usda"), (inner, "inner.usdz")])
    scene = load_scene(_set_referencing(tmp_path / "set.usda", "./outer.usdz"), default_light=False)
    assert not any("missing" in w or "composition" in w for w in scene.warnings), scene.warnings
    _centre_is_red(scene)
    # Submitted as the bundle itself, the outer package is unpacked; the inner stays a package.
    _centre_is_red(load_scene(tmp_path / "outer.usdz", default_light=False))


def test_package_members_obey_the_sandbox(tmp_path):
    from tessera_renderer import SceneError

    # A member climbing out of its package to a file beside it is refused, not read.
    layer = _red_asset_layer(tmp_path / "src", texture="../tex.png")
    (tmp_path / "tex.png").write_bytes((layer.parent / "tex.png").read_bytes())
    _usdz(tmp_path / "asset.usdz", [(layer, "asset.usda")])
    path = _set_referencing(tmp_path / "set.usda", "./asset.usdz")
    with pytest.raises(SceneError, match="outside its package"):
        load_scene(path)
    # A member that is not in the package is reported missing (and the quad falls back).
    layer = _red_asset_layer(tmp_path / "src2", texture="./absent.png")
    _usdz(tmp_path / "asset2.usdz", [(layer, "asset.usda")])
    data = translate_stage(_set_referencing(tmp_path / "set2.usda", "./asset2.usdz"))
    assert any("absent.png" in w and "missing" in w for w in data.warnings)


# -- 4. variants: what the composed stage uses ---------------------------------------------
@pytest.fixture()
def car_kit(tmp_path):
    import shutil

    src = require_shared_scenes() / "usdwg_mini_car_kit"
    work = tmp_path / "kit"
    shutil.copytree(src, work)
    return work


def _lit_fraction(scene, w=32, h=24):
    img = scene.render_tile(0, 0, w, h, width=w, height=h, spp=4, max_depth=3)
    return float((img[..., :3].max(axis=2) > 0.05).mean())


@pytest.mark.shared_scenes
def test_layer_of_an_unselected_variant_may_be_missing(car_kit):
    from tessera_renderer import SceneError

    vehicles = car_kit / "USD_Mini_Car_Kit" / "assets" / "vehicles"
    # The real kit selects the tractor; the ambulance's layers are only in another variant.
    import shutil
    shutil.rmtree(vehicles / "ambulance")
    scene = load_scene(vehicles / "vehicleVariants.usda", root=car_kit)
    info = [w for w in scene.warnings if w.startswith("information:")]
    assert len(info) == 1 and "ambulanceFullAsset.usda" in info[0] and "not used" in info[0]
    assert scene.num_triangles == 1988  # the tractor, as with the complete kit
    assert _lit_fraction(scene) > 0.1
    # A stronger layer selecting the ambulance asks for the missing layer: fatal, named.
    shot = car_kit / "shot.usda"
    shot.write_text('#usda 1.0\n(defaultPrim = "Car")\n'
                    'def "Car" (references = @./USD_Mini_Car_Kit/assets/vehicles/vehicleVariants.usda@\n'
                    '           variants = {string wheels = "sedan"})\n{}\n')
    assert load_scene(shot, root=car_kit).num_triangles > 0  # sedan: present
    shot.write_text(shot.read_text().replace('"sedan"', '"ambulance"'))
    with pytest.raises(SceneError, match="ambulanceFullAsset.usda' is not in the bundle"):
        load_scene(shot, root=car_kit)


@pytest.mark.shared_scenes
def test_missing_layer_of_the_selected_variant_or_a_sublayer_is_fatal(car_kit, tmp_path):
    from tessera_renderer import SceneError

    vehicles = car_kit / "USD_Mini_Car_Kit" / "assets" / "vehicles"
    (vehicles / "tractor" / "asset" / "tractorFullAsset.usda").unlink()
    with pytest.raises(SceneError, match="tractorFullAsset.usda' is not in the bundle"):
        load_scene(vehicles / "vehicleVariants.usda", root=car_kit)
    (tmp_path / "sub.usda").write_text('#usda 1.0\n(subLayers = [@./gone.usda@])\n')
    with pytest.raises(SceneError, match="gone.usda' is not in the bundle"):
        load_scene(tmp_path / "sub.usda")


@pytest.mark.shared_scenes
def test_a_render_selects_variants_and_says_what_it_cannot_select(car_kit, tmp_path):
    """The kit's own file selects the tractor; a render may select another vehicle
    (load_scene variants=, tessera render --variant) and then draws that one; a missing
    layer becomes fatal when the render selects its variant; an unknown prim, set or
    variant is refused naming the choices."""
    import subprocess
    import sys

    from tessera_renderer import SceneError

    vehicles = car_kit / "USD_Mini_Car_Kit" / "assets" / "vehicles"
    scene_file = vehicles / "vehicleVariants.usda"
    tractor = load_scene(scene_file, root=car_kit)
    sedan = load_scene(scene_file, root=car_kit, variants=[("/vehicleVariant", "wheels", "sedan")])
    assert tractor.num_triangles == 1988 and sedan.num_triangles not in (0, 1988)
    # The sedan as a stronger layer selects it: the same triangles (the real kit's own data).
    shot = tmp_path / "shot.usda"
    shot.write_text(f'#usda 1.0\n(defaultPrim = "Car")\ndef "Car" (references = @{scene_file}@\n'
                    '           variants = {string wheels = "sedan"})\n{}\n')
    assert load_scene(shot, root="/").num_triangles == sedan.num_triangles
    for variants, words in (([("/vehicleVariant", "wheels", "boat")], "has no variant 'boat' (choices: 4wd, amb"),
                            ([("/vehicleVariant", "paint", "red")], "has no variant set 'paint' (its sets: wheels)"),
                            ([("/Nowhere", "wheels", "sedan")], "the stage has no prim /Nowhere")):
        with pytest.raises(SceneError, match=re.escape(words)):
            load_scene(scene_file, root=car_kit, variants=variants)
    import shutil
    shutil.rmtree(vehicles / "ambulance")
    assert load_scene(scene_file, root=car_kit).num_triangles == 1988  # unselected: information only
    with pytest.raises(SceneError, match="ambulanceFullAsset.usda' is not in the bundle"):
        load_scene(scene_file, root=car_kit, variants=[("/vehicleVariant", "wheels", "ambulance")])
    # The CLI: --variant selects; a malformed one is refused before anything is read.
    out = tmp_path / "sedan.exr"
    r = subprocess.run([sys.executable, "-m", "tessera", "render", str(scene_file), "--root", str(car_kit),
                        "--variant", "/vehicleVariant:wheels=sedan", "--spp", "1", "--res", "16x12", "-q",
                        "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    from tessera import render
    from tessera_base import images
    expected = render(str(scene_file), root=car_kit, variants=["/vehicleVariant:wheels=sedan"], res=(16, 12),
                      spp=1).rgba  # tessera.render selects it the same way, bit for bit
    np.testing.assert_array_equal(images.read_exr(out), expected)
    assert not np.array_equal(expected, render(str(scene_file), root=car_kit, res=(16, 12), spp=1).rgba)
    r = subprocess.run([sys.executable, "-m", "tessera", "render", str(scene_file), "--variant", "wheels=sedan"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "must be /Prim/Path:set=value" in r.stderr, r.stderr


# -- 8. default camera: a tight three-quarter view ----------------------------------------
def _coverage_box(alpha):
    """(top, bottom, left, right) margins in pixels of the geometry's silhouette."""
    rows, cols = np.nonzero(alpha > 0.5)
    h, w = alpha.shape
    return rows.min(), h - 1 - rows.max(), cols.min(), w - 1 - cols.max()


@pytest.mark.parametrize("up,faces", [("Y", [(1, 0, 0), (0, 1, 0), (0, 0, 1)]),
                                      ("Z", [(1, 0, 0), (0, -1, 0), (0, 0, 1)])])
def test_camera_less_stage_is_framed_tightly_from_three_quarters(tmp_path, up, faces):
    stage = new_stage(tmp_path / "cube.usda")
    UsdGeom.SetStageUpAxis(stage, up)
    cube = UsdGeom.Cube.Define(stage, "/Cube")
    cube.CreateSizeAttr(2.0)
    cube.AddTranslateOp().Set(Gf.Vec3d(10, -4, 3))  # framing follows the bounds, wherever
    scene = load_scene(save_stage(stage))
    assert any("three-quarter" in w for w in scene.warnings)
    w, h = 64, 48
    rgba, aov = scene.render_tile(0, 0, w, h, width=w, height=h, spp=4, aovs=("normal",))
    # Three faces show, each over 10 % of the frame: front, side and top.
    n = aov["normal"].reshape(-1, 3)
    for face in faces:
        share = float((n @ np.array(face, float) > 0.99).mean())
        assert share > 0.10, (face, share)
    # Tight: the silhouette fills the frame's height to within 5 % + a pixel at each end,
    # centred (margins differ by at most 2 pixels).
    top, bottom, left, right = _coverage_box(rgba[..., 3])
    assert top <= 0.025 * h + 1 and bottom <= 0.025 * h + 1 and abs(top - bottom) <= 2, (top, bottom)
    assert abs(left - right) <= 2, (left, right)


@pytest.mark.shared_scenes
def test_real_teapot_fills_the_frame(tmp_path):
    scene = load_scene(SCENES / "usdwg_teapot" / "Teapot.usd")
    w, h = 64, 64
    rgba = scene.render_tile(0, 0, w, h, width=w, height=h, spp=2, max_depth=2)
    top, bottom, left, right = _coverage_box(rgba[..., 3])
    # The silhouette reaches within 5 % of two opposite edges (the old front view at the
    # bounding sphere's distance left a third of the frame empty on every side).
    assert min(top + bottom, left + right) <= 0.05 * w + 2, (top, bottom, left, right)
    assert float((rgba[..., 3] > 0.5).mean()) > 0.3


# -- 10. opacity as exporters mean it -----------------------------------------------------
def _pane_scene(tmp_path, name, **inputs):
    """A black UsdPreviewSurface pane (half size 1, z = 0) in front of a backdrop emitting
    radiance 1 toward the camera (z = -1), seen by a camera at z = 5 looking down -Z.
    Nothing lights the pane's front, so a pixel through it shows exactly the share of the
    backdrop that passes the pane."""
    from usd_fixtures import add_camera

    stage = new_stage(tmp_path / f"{name}.usda")
    add_quad(stage, "/Backdrop", size=4.0, z=-1.0, material=add_material(stage, "/Looks/Bd", (0, 0, 0), (1, 1, 1)))
    glass = add_material(stage, "/Looks/Glass", (0, 0, 0))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Glass/Surface"))
    for key, value in inputs.items():
        kind = Sdf.ValueTypeNames.Token if isinstance(value, str) else Sdf.ValueTypeNames.Float
        shader.CreateInput(key, kind).Set(value)
    add_quad(stage, "/Pane", size=1.0, z=0.0, material=glass)
    add_camera(stage, "/Camera", translate=(0, 0, 5), focal=50.0, haperture=36.0, vaperture=36.0)
    return load_scene(save_stage(stage))


def test_partial_opacity_is_presence_as_usdview_shows_it(tmp_path):
    scene = _pane_scene(tmp_path, "mineways_glass", opacity=0.57)  # Mineways writes 0.57, no ior
    assert scene.data.material_params["opacity_threshold"].min() < 0  # presence row
    assert any("presence" in w for w in scene.warnings)
    w = h = 64
    rgba, var = scene.render_tile(0, 0, w, h, width=w, height=h, spp=512, seed=3, return_variance=True)
    box = (slice(20, 44), slice(20, 44))  # well inside the pane (it covers the central 55 %)
    px, v = rgba[box][..., 0].ravel(), var[box][..., 0].ravel() / 512
    mean, se = float(px.mean()), float(math.sqrt(v.sum()) / len(px))
    expected = 1.0 - 0.57  # the transmitted share, no Fresnel loss, no refraction
    assert 0.02 * expected > 8 * se, "the check must detect a 2 % error"
    assert _agrees(mean, se, expected), (mean, se, expected)
    assert not _agrees(mean, se, expected * 1.02) and not _agrees(mean, se, expected * 0.98)
    # Outside the pane the backdrop shows unattenuated.
    assert rgba[2, 2, 0] == pytest.approx(1.0, abs=1e-3)


def test_refraction_only_where_authored_and_presence_mode(tmp_path):
    glass = _pane_scene(tmp_path, "ior", opacity=0.57, ior=1.5).data.material_params
    assert glass["opacity_threshold"].max() == 0.0 and glass["opacity"].min() == pytest.approx(0.57)
    clear = _pane_scene(tmp_path, "clear", opacity=0.0).data.material_params  # clear glass stays glass
    assert clear["opacity_threshold"].max() == 0.0
    presence = _pane_scene(tmp_path, "presence", opacity=0.3, ior=1.5, opacityMode="presence")
    assert presence.data.material_params["opacity_threshold"].min() < 0
    cutout = _pane_scene(tmp_path, "cutout", opacity=0.3, opacityThreshold=0.5).data.material_params
    assert cutout["opacity_threshold"].max() == pytest.approx(0.5)


def test_normal_maps_without_scale_and_bias_warn_once_per_asset(tmp_path):
    import OpenImageIO as oiio

    oiio.ImageBuf(np.full((2, 2, 3), (128, 128, 255), np.uint8)).write(str(tmp_path / "n.png"))
    stage = new_stage(tmp_path / "normals.usda")
    for k in range(3):  # three materials, each with an unscaled normal map
        mat = add_material(stage, f"/Looks/M{k}", (0.2 * k, 0.5, 0.5))
        tex = UsdShade.Shader.Define(stage, f"/Looks/M{k}/N")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./n.png")
        UsdShade.Shader(stage.GetPrimAtPath(f"/Looks/M{k}/Surface")).CreateInput(
            "normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
        add_quad(stage, f"/Q{k}", z=float(k), material=mat)
    data = translate_stage(save_stage(stage))
    lines = [w for w in data.warnings if "normal maps" in w]
    assert len(lines) == 1 and "usdview" in lines[0], data.warnings
    # Read as authored: the texture's scale and bias stay the schema's (1, 0).
    normal_textures = [data.textures[t] for (m, name), t in data.material_textures.items() if name == "normal"]
    assert len(normal_textures) >= 1 and all(t["scale"][:3] == [1.0, 1.0, 1.0] for t in normal_textures)


# -- 9a. skinned meshes (UsdSkel) -----------------------------------------------------------
def _skinned_bar(tmp_path):
    """What Blender's and Maya's exporters write for a rigged bar: SkelRoot > Skeleton (two
    joints: root at the origin, tip 1 up the bar) + Mesh bound with jointIndices/
    jointWeights (vertex interpolation, one influence), and a SkelAnimation that bends the
    tip 90° about +Z between frames 1 and 10. The bar is 0.2 thick, 2 long along +Y: the
    lower half is bound to the root, the upper half to the tip."""
    from pxr import UsdSkel

    stage = new_stage(tmp_path / "rig.usda")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(10)
    root = UsdSkel.Root.Define(stage, "/Rig")
    root.GetPrim().CreateAttribute("xformOp:translate", Sdf.ValueTypeNames.Double3).Set(Gf.Vec3d(5, 0, 0))
    UsdGeom.Xformable(root.GetPrim()).CreateXformOpOrderAttr().Set(["xformOp:translate"])
    skel = UsdSkel.Skeleton.Define(stage, "/Rig/Skel")
    skel.CreateJointsAttr(["root", "root/tip"])
    identity = Gf.Matrix4d(1)
    tip_rest = Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 1, 0))
    skel.CreateBindTransformsAttr([identity, tip_rest])         # world-space bind pose
    skel.CreateRestTransformsAttr([identity, tip_rest])         # joint-local rest pose
    anim = UsdSkel.Animation.Define(stage, "/Rig/Skel/Anim")
    anim.CreateJointsAttr(["root", "root/tip"])
    anim.CreateTranslationsAttr().Set([Gf.Vec3f(0, 0, 0), Gf.Vec3f(0, 1, 0)])
    anim.CreateScalesAttr().Set([Gf.Vec3h(1, 1, 1), Gf.Vec3h(1, 1, 1)])
    rot = anim.CreateRotationsAttr()
    bent = Gf.Quatf(math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4))  # 90° about +Z
    rot.Set([Gf.Quatf(1, 0, 0, 0), Gf.Quatf(1, 0, 0, 0)], 1)
    rot.Set([Gf.Quatf(1, 0, 0, 0), bent], 10)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    # A 2 x 1 x 1 grid of boxes along y: rows at y = 0, 1, 2.
    pts, t = [], 0.1
    for y in (0.0, 1.0, 2.0):
        pts += [(-t, y, -t), (t, y, -t), (t, y, t), (-t, y, t)]
    quads = []
    for r in range(2):
        a, b = 4 * r, 4 * r + 4
        quads += [(a + i, a + (i + 1) % 4, b + (i + 1) % 4, b + i) for i in range(4)]
    quads += [(0, 3, 2, 1), (8, 9, 10, 11)]
    mesh = add_mesh(stage, "/Rig/Bar", pts, [4] * len(quads), [i for q in quads for i in q])
    mesh.CreateDisplayColorAttr([Gf.Vec3f(0.8, 0.8, 0.8)])
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointIndicesPrimvar(False, 1).Set([0] * 4 + [1] * 8)  # rows at y >= 1: the tip
    binding.CreateJointWeightsPrimvar(False, 1).Set([1.0] * 12)
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1))
    return save_stage(stage)


def test_a_skinned_mesh_posed_during_the_shutter_deforms_through_its_pose(tmp_path):
    """The rigged bar at frame 5 with a shutter from frame 3 to 7: the tip turns 90° over
    frames 1-10 (slerp between the keys: 10° a frame), so during the shutter it sweeps
    from 20° to 60°. Every time step of the deforming prototype holds the top row where
    the closed form puts it, the joint at (0, 1, 0) turned by 10° (t - 1) about +Z; the
    root half stands still. Without a shutter the bar is posed at the frame alone."""
    path = _skinned_bar(tmp_path)
    data = translate_stage(path, frame=5, shutter=(-2.0, 2.0), camera_relative=False)
    (proto,) = [p for p in data.prototypes if p.get("motion_positions") is not None]
    steps = np.concatenate([proto["positions"][None], proto["motion_positions"]]).astype(np.float64)
    assert len(steps) > 2  # a turn of 40° needs more than its two ends
    for k, step in enumerate(steps):
        theta = np.radians(10.0 * (3.0 + 4.0 * k / (len(steps) - 1) - 1.0))
        top = step[np.abs(step[:, 1] - step[:, 1].max()) < 0.25]  # the tip's far row
        for dx in (-0.1, 0.1):  # (dx, 1) from the joint, turned by theta
            want = (dx * np.cos(theta) - np.sin(theta), 1.0 + dx * np.sin(theta) + np.cos(theta))
            assert np.min(np.hypot(top[:, 0] - want[0], top[:, 1] - want[1])) < 1e-4, (k, theta, top)
        root = step[np.abs(step[:, 1]) < 1e-6]  # the bottom row, bound to the still root
        np.testing.assert_allclose(np.abs(root[:, [0, 2]]), 0.1, atol=1e-6)
    assert not any("not motion-blurred" in w for w in data.warnings), data.warnings
    assert any("1 of them motion-blurred" in w for w in data.warnings), data.warnings
    still = translate_stage(path, frame=5, shutter=(0.0, 0.0), camera_relative=False)
    assert not any(p.get("motion_positions") is not None for p in still.prototypes)
    # A SkelRoot keyed to slide from x = 5 to 6 over the shutter carries the bending bar:
    # its instance moves with the skeleton.
    stage = Usd.Stage.Open(path)
    op = stage.GetPrimAtPath("/Rig").GetAttribute("xformOp:translate")
    op.Set(Gf.Vec3d(5, 0, 0), 3.0)
    op.Set(Gf.Vec3d(6, 0, 0), 7.0)
    save_stage(stage)
    moving = translate_stage(path, frame=5, shutter=(-2.0, 2.0), camera_relative=False)
    assert len(moving.motion_instances) == 1
    xs = np.asarray(moving.motion_transforms, np.float64).reshape(-1, 4, 4)[:, 3, 0]
    np.testing.assert_allclose(xs[[0, -1]], [5.0, 6.0], atol=1e-9)


def test_skinned_mesh_is_posed_at_the_render_frame(tmp_path):
    path = _skinned_bar(tmp_path)
    rest = translate_stage(path, frame=1, camera_relative=False)
    bent = translate_stage(path, frame=10, camera_relative=False)
    assert not any("skipped" in w or "not supported" in w for w in bent.warnings), bent.warnings
    # Rest pose: the bar stands along +Y from y = 0 to 2 at x = 5 (the SkelRoot's offset).
    np.testing.assert_allclose(rest.positions.min(axis=0), (4.9, 0.0, -0.1), atol=1e-5)
    np.testing.assert_allclose(rest.positions.max(axis=0), (5.1, 2.0, 0.1), atol=1e-5)
    # Frame 10: the tip half turns 90° about +Z around the joint at (5, 1, 0): its top row
    # (y = 2, x = 5 +- 0.1) goes to x = 5 - 1 = 4, y = 1 +- 0.1 (closed form).
    top = bent.positions[np.abs(bent.positions[:, 0] - 4.0) < 1e-4]
    assert len(top) >= 4
    np.testing.assert_allclose(sorted(set(np.round(top[:, 1], 5))), [0.9, 1.1], atol=1e-5)
    assert bent.positions[:, 0].min() == pytest.approx(4.0, abs=1e-5)
    assert bent.positions[:, 1].max() == pytest.approx(1.1, abs=1e-5)
    # The render shows the bent bar: the bent tip is covered where the rest pose has none.
    from usd_fixtures import add_camera
    stage = Usd.Stage.Open(path)
    add_camera(stage, "/Camera", translate=(4.5, 1.0, 10), focal=50.0, haperture=36.0, vaperture=36.0)
    save_stage(stage)
    w = h = 48
    for frame, tip_covered in ((1, False), (10, True)):
        scene = load_scene(path, frame=frame)
        alpha = scene.render_tile(0, 0, w, h, width=w, height=h, spp=4)[..., 3]
        row, col = _pixel_of(scene, (4.2, 1.0, 0.0), w, h)  # on the bent tip, off the rest bar
        assert (alpha[row, col] > 0.5) == tip_covered, (frame, alpha[row, col])
