"""MaterialX looks as DCC tools write them (issues 11 and 43): inline standard_surface and
open_pbr_surface shaders with image nodes, MaterialX documents referenced, payloaded or
sublayered from USD, math folded into textures, and the one line naming grey fallbacks.
Split from test_dcc_usd.py; the same rules: every image check is one a black or grey image
fails."""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade

from conftest import SHARED_SCENES
from tessera_renderer import load_scene
from tessera_renderer.usd import translate_stage
from usd_fixtures import add_quad, lightless_quad, new_stage, save_stage, write_four_texel_png

SCENES = SHARED_SCENES


# -- 5. MaterialX looks ---------------------------------------------------------------------
def _mtlx_node(stage, path, ident, **inputs):
    node = UsdShade.Shader.Define(stage, path)
    node.CreateIdAttr(ident)
    for name, (kind, value) in inputs.items():
        node.CreateInput(name, kind).Set(value)
    return node


def test_inline_materialx_standard_surface_with_an_image_node(tmp_path):
    """What Houdini's Karma material builder and Omniverse write: outputs:mtlx:surface ->
    ND_standard_surface_surfaceshader, base and emission colour from ND_image_color3 in a
    NodeGraph whose texcoord is a ND_geompropvalue_vector2 naming the UV set."""
    write_four_texel_png(tmp_path / "four.png")
    stage = new_stage(tmp_path / "houdini.usda")
    mat = UsdShade.Material.Define(stage, "/Looks/M")
    graph = UsdShade.NodeGraph.Define(stage, "/Looks/M/NG")
    uv = _mtlx_node(stage, "/Looks/M/NG/uv", "ND_geompropvalue_vector2",
                    geomprop=(Sdf.ValueTypeNames.String, "uv_houdini"))
    img = _mtlx_node(stage, "/Looks/M/NG/img", "ND_image_color3")
    img.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./four.png")
    img.GetInput("file").GetAttr().SetColorSpace("lin_rec709")
    img.CreateInput("texcoord", Sdf.ValueTypeNames.Float2).ConnectToSource(uv.ConnectableAPI(), "out")
    graph.CreateOutput("color", Sdf.ValueTypeNames.Color3f).ConnectToSource(img.ConnectableAPI(), "out")
    surf = _mtlx_node(stage, "/Looks/M/Surface", "ND_standard_surface_surfaceshader",
                      base=(Sdf.ValueTypeNames.Float, 0.0), emission=(Sdf.ValueTypeNames.Float, 1.0),
                      specular=(Sdf.ValueTypeNames.Float, 0.0), metalness=(Sdf.ValueTypeNames.Float, 0.25))
    surf.CreateInput("emission_color", Sdf.ValueTypeNames.Color3f).ConnectToSource(graph.GetOutput("color"))
    surf.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf.ConnectableAPI(), "surface")
    mesh = add_quad(stage, material=mat)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("uv_houdini", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.vertex).Set([Gf.Vec2f(0.75, 0.75)] * 4)
    scene = load_scene(save_stage(stage))
    assert not any("grey" in w for w in scene.warnings), scene.warnings
    assert scene.data.material_params["metallic"].max() == pytest.approx(0.25)
    img = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=2)
    np.testing.assert_allclose(img[8, 8, :3], (0.0, 1.0, 0.0), atol=0.01)  # the green texel


def test_inline_open_pbr_constants_map_to_the_bsdf(tmp_path):
    stage = new_stage(tmp_path / "openpbr.usda")
    mat = UsdShade.Material.Define(stage, "/Looks/M")
    surf = _mtlx_node(stage, "/Looks/M/S", "ND_open_pbr_surface_surfaceshader",
                      base_color=(Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.2, 0.4, 0.6)),
                      base_weight=(Sdf.ValueTypeNames.Float, 0.5),
                      specular_roughness=(Sdf.ValueTypeNames.Float, 0.7),
                      coat_weight=(Sdf.ValueTypeNames.Float, 0.3),
                      geometry_opacity=(Sdf.ValueTypeNames.Float, 0.6))
    surf.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf.ConnectableAPI(), "surface")
    add_quad(stage, material=mat)
    d = translate_stage(save_stage(stage))
    np.testing.assert_allclose(d.albedo[0], (0.1, 0.2, 0.3), atol=1e-6)  # base_color x base_weight
    p = d.material_params
    assert p["roughness"][0] == pytest.approx(0.7) and p["clearcoat"][0] == pytest.approx(0.3)
    assert p["ior"][0] == pytest.approx(1.5)  # the node definition's default specular_ior
    assert p["opacity"][0] == pytest.approx(0.6) and p["opacity_threshold"][0] < 0  # coverage: presence
    assert p["preview_surface"][0] == 1.0


def test_materialx_document_referenced_from_usd(tmp_path):
    """The usdMtlx convention (OpenChessSet-style looks): a Material prim references a
    .mtlx document's material; usd-core cannot compose it, Tessera reads it itself."""
    import MaterialX as mx

    write_four_texel_png(tmp_path / "four.png")
    doc = mx.createDocument()
    graph = doc.addNodeGraph("NG_look")
    image = graph.addNode("image", "img", "color3")
    image.setInputValue("file", "four.png", "filename")
    image.getInput("file").setColorSpace("lin_rec709")
    graph.addOutput("out", "color3").setConnectedNode(image)
    shader = doc.addNode("standard_surface", "SR_look", "surfaceshader")
    shader.setInputValue("base", 0.0)
    shader.setInputValue("specular", 0.0)
    shader.setInputValue("emission", 1.0)
    emission = shader.addInput("emission_color", "color3")
    emission.setNodeGraphString("NG_look")
    emission.setOutputString("out")
    doc.addMaterialNode("Look", shader)
    mx.writeToXmlFile(doc, str(tmp_path / "look.mtlx"))
    stage = new_stage(tmp_path / "chess.usda")
    mat = UsdShade.Material.Define(stage, "/Looks/Look")
    mat.GetPrim().GetReferences().AddReference("./look.mtlx", "/MaterialX/Materials/Look")
    mesh = add_quad(stage, material=mat)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.vertex).Set([Gf.Vec2f(0.25, 0.25)] * 4)
    scene = load_scene(save_stage(stage))
    assert not any("grey" in w for w in scene.warnings), scene.warnings
    img = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=2)
    np.testing.assert_allclose(img[8, 8, :3], (0.0, 0.0, 1.0), atol=0.01)  # the blue texel


def test_one_summary_line_names_every_grey_material(tmp_path):
    stage = new_stage(tmp_path / "grey.usda")
    odd = UsdShade.Material.Define(stage, "/Looks/Odd")
    s = _mtlx_node(stage, "/Looks/Odd/S", "ND_gltf_pbr_surfaceshader")
    s.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    odd.CreateSurfaceOutput("mtlx").ConnectToSource(s.ConnectableAPI(), "surface")
    empty = UsdShade.Material.Define(stage, "/Looks/Empty")
    add_quad(stage, "/A", material=odd)
    add_quad(stage, "/B", z=1.0, material=empty)
    data = translate_stage(save_stage(stage))
    lines = [w for w in data.warnings if "grey" in w]
    assert lines == ["2 material(s) fell back to the default grey: /Looks/Empty (no surface shader), "
                     "/Looks/Odd (ND_gltf_pbr_surfaceshader)"], data.warnings


@pytest.mark.shared_scenes
def test_real_teapot_keeps_its_universal_preview_surface():
    path = SCENES / "usdwg_intent_vfx_instancing" / "assets" / "teapot" / "mtl.usd"
    data = translate_stage(str(path), root=str(SCENES / "usdwg_intent_vfx_instancing"))
    # Both surfaces are authored; the universal UsdPreviewSurface (green) wins, as in Storm.
    assert any(np.allclose(a, (0.107700236, 0.90119886, 0.038153667), atol=1e-6) for a in data.albedo)


def test_a_referenced_mtlx_is_not_reported_as_a_composition_error(tmp_path):
    import MaterialX as mx

    doc = mx.createDocument()
    shader = doc.addNode("standard_surface", "SR", "surfaceshader")
    shader.setInputValue("base_color", mx.Color3(0.1, 0.2, 0.3))
    doc.addMaterialNode("Look", shader)
    mx.writeToXmlFile(doc, str(tmp_path / "look.mtlx"))
    stage = new_stage(tmp_path / "s.usda")
    mat = UsdShade.Material.Define(stage, "/Looks/Look")
    mat.GetPrim().GetReferences().AddReference("./look.mtlx", "/MaterialX/Materials/Look")
    add_quad(stage, material=mat)
    data = translate_stage(save_stage(stage))
    assert not any(w.startswith("composition") for w in data.warnings), data.warnings
    # standard_surface: base (default 1) x base_color
    np.testing.assert_allclose(data.albedo[0], (0.1, 0.2, 0.3), atol=1e-6)


def test_render_child_honours_the_job_setting(tmp_path):
    """The worker's render process builds the Scene from one blob with or without the
    default lighting, as the task's settings say."""
    from tessera_worker.render_child import _blob_api, _load

    path = lightless_quad(tmp_path)
    api, _ = _blob_api()
    lit = _load({"scene_path": path, "default_light": True}, api)
    unlit = _load({"scene_path": path, "default_light": False}, api)
    assert lit.render_tile(0, 0, 8, 8, width=8, height=8, spp=2)[4, 4, 0] > 0.2
    assert unlit.render_tile(0, 0, 8, 8, width=8, height=8, spp=2)[..., :3].max() == 0.0


def test_materialx_math_on_an_image_folds_into_the_texture(tmp_path):
    """Affine math a look builder writes around an image -- image x colour + colour, and a
    mix of the image with a constant by a constant weight -- renders as that arithmetic on
    the texel (emission seen head-on, the green texel (0, 1, 0)); two images multiplied are
    not evaluated and say so."""
    write_four_texel_png(tmp_path / "four.png")
    colour = Sdf.ValueTypeNames.Color3f

    def scene_with(name: str, build) -> str:
        stage = new_stage(tmp_path / f"{name}.usda")
        mat = UsdShade.Material.Define(stage, "/Looks/M")
        img = _mtlx_node(stage, "/Looks/M/img", "ND_image_color3")
        img.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./four.png")
        img.GetInput("file").GetAttr().SetColorSpace("lin_rec709")
        out = build(stage, img)
        surf = _mtlx_node(stage, "/Looks/M/Surface", "ND_standard_surface_surfaceshader",
                          base=(Sdf.ValueTypeNames.Float, 0.0), emission=(Sdf.ValueTypeNames.Float, 1.0),
                          specular=(Sdf.ValueTypeNames.Float, 0.0))
        surf.CreateInput("emission_color", colour).ConnectToSource(out.ConnectableAPI(), "out")
        surf.CreateOutput("surface", Sdf.ValueTypeNames.Token)
        mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf.ConnectableAPI(), "surface")
        mesh = add_quad(stage, material=mat)
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                UsdGeom.Tokens.vertex).Set([Gf.Vec2f(0.75, 0.75)] * 4)
        return save_stage(stage)

    def scaled_and_offset(stage, img):
        mul = _mtlx_node(stage, "/Looks/M/mul", "ND_multiply_color3", in2=(colour, Gf.Vec3f(0.5, 0.25, 0.5)))
        mul.CreateInput("in1", colour).ConnectToSource(img.ConnectableAPI(), "out")
        add = _mtlx_node(stage, "/Looks/M/add", "ND_add_color3", in2=(colour, Gf.Vec3f(0.1, 0.2, 0.0)))
        add.CreateInput("in1", colour).ConnectToSource(mul.ConnectableAPI(), "out")
        return add

    def mixed(stage, img):
        mix = _mtlx_node(stage, "/Looks/M/mix", "ND_mix_color3", bg=(colour, Gf.Vec3f(1.0, 0.0, 0.0)),
                         mix=(Sdf.ValueTypeNames.Float, 0.25))
        mix.CreateInput("fg", colour).ConnectToSource(img.ConnectableAPI(), "out")
        return mix

    def squared(stage, img):
        mul = _mtlx_node(stage, "/Looks/M/sq", "ND_multiply_color3")
        for inp in ("in1", "in2"):
            mul.CreateInput(inp, colour).ConnectToSource(img.ConnectableAPI(), "out")
        return mul

    # green x (0.5, 0.25, 0.5) + (0.1, 0.2, 0); 0.25 x green + 0.75 x red.
    for name, build, want in (("affine", scaled_and_offset, (0.1, 0.45, 0.0)), ("mix", mixed, (0.75, 0.25, 0.0))):
        scene = load_scene(scene_with(name, build))
        assert not any("not evaluated" in w for w in scene.warnings), scene.warnings
        img = scene.render_tile(0, 0, 16, 16, width=16, height=16, spp=2)
        np.testing.assert_allclose(img[8, 8, :3], want, atol=0.01, err_msg=name)
    warnings = translate_stage(scene_with("square", squared)).warnings
    assert any("two images is not evaluated" in w for w in warnings), warnings


def _two_looks_mtlx(path):
    """A MaterialX document as Houdini writes an asset's looks: two standard_surface
    materials, "Red" and "Blue", with authored base colours."""
    import MaterialX as mx

    doc = mx.createDocument()
    for name, color in (("Red", (0.7, 0.1, 0.05)), ("Blue", (0.05, 0.2, 0.6))):
        shader = doc.addNode("standard_surface", f"SR_{name}", "surfaceshader")
        shader.setInputValue("base_color", mx.Color3(*color))
        doc.addMaterialNode(name, shader)
    mx.writeToXmlFile(doc, str(path))


@pytest.mark.parametrize("arc", ["reference", "payload", "sublayer", "bound prim"])
def test_mtlx_layers_referenced_payloaded_or_sublayered_bind_as_the_file_binds_them(tmp_path, arc):
    """Issue 43: `references = @./asset_mat.mtlx@</MaterialX/Materials>` on a scope (or a
    payload, or the document as a sublayer): usd-core composes no prim there, the meshes'
    bindings dangle; Tessera reads each bound material from the document. A binding to a
    material the document lacks is named in the one grey line (negative control)."""
    _two_looks_mtlx(tmp_path / "asset_mat.mtlx")
    stage = new_stage(tmp_path / "asset.usda")
    prefix = ""
    if arc == "sublayer":
        stage.GetRootLayer().subLayerPaths.append("./asset_mat.mtlx")
        looks = "/MaterialX/Materials"
    elif arc == "bound prim":  # typeless prims, each referencing the material its arc names
        looks, prefix = "/Asset/Looks", "M_"
        for look in ("Red", "Blue", "Green"):
            stage.OverridePrim(f"{looks}/{prefix}{look}").GetReferences().AddReference(
                "./asset_mat.mtlx", f"/MaterialX/Materials/{look}")
    else:
        scope = stage.DefinePrim("/Asset/Materials", "Scope")
        (scope.GetReferences().AddReference if arc == "reference" else scope.GetPayloads().AddPayload)(
            "./asset_mat.mtlx", "/MaterialX/Materials")
        looks = "/Asset/Materials"
    for k, (name, look) in enumerate((("A", "Red"), ("B", "Blue"), ("C", "Green"))):
        mesh = add_quad(stage, f"/Asset/Geo/{name}", z=float(k))
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).GetDirectBindingRel().SetTargets([f"{looks}/{prefix}{look}"])
    data = translate_stage(save_stage(stage))
    for authored in ((0.7, 0.1, 0.05), (0.05, 0.2, 0.6)):  # standard_surface: base 1 x base_color
        assert any(np.allclose(a, authored, atol=1e-6) for a in data.albedo), (authored, data.albedo)
    lines = [w for w in data.warnings if "grey" in w]
    assert lines == [f"1 material(s) fell back to the default grey: {looks}/{prefix}Green (no material 'Green' in "
                     f"asset_mat.mtlx)"], data.warnings
