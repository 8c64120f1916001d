"""A loose layer's dependencies are gathered for packing (tessera_renderer.usd.packing), and a
local `tessera render` trusts the user's own files unless --sandbox asks for the upload
sandbox."""
from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import SHARED_SCENES
from test_bundles import MESH, layer

SCENES = SHARED_SCENES
CAR_KIT = SCENES / "usdwg_mini_car_kit" / "USD_Mini_Car_Kit"
SHARED = [CAR_KIT / "assets" / "vehicles" / "vehicleVariants.usda",
          SCENES / "usdwg_teapot" / "Teapot.usd",
          SCENES / "usdwg_intent_vfx_instancing" / "scenes" / "teapotScene_layout.usd",
          SCENES / "usdwg_texture_formats" / "all_files.usda"]
# The project's files as make_project writes them: the pack must be exactly these.
PROJECT_FILES = {"scenes/shot.usda", "lib/lights.usda", "assets/prop.usda", "assets/parts/extra.usda",
                 "textures/t.png", "top.usda"}


def write_texture(path: Path, rgb: tuple[int, int, int]) -> Path:
    from OpenImageIO import ImageBuf

    path.parent.mkdir(parents=True, exist_ok=True)
    ImageBuf(np.tile(np.array(rgb, np.uint8), (4, 4, 1))).write(str(path))
    return path


def make_project(root: Path, rgb=(200, 60, 30)) -> Path:
    """A shot in scenes/ whose sublayer, references and texture all lie in sibling folders
    (../lib, ../assets, ../textures) or above it (../top.usda, the only USD file at the
    project's top level), plus one texture path that names nothing. Returns the shot."""
    light = layer(textwrap.dedent("""\
        def DomeLight "Sky" {
            float inputs:intensity = 1
        }
    """))
    material = textwrap.dedent("""\
        def Material "Mat" {
            token outputs:surface.connect = </P/Mat/S.outputs:surface>
            def Shader "S" {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </P/Mat/T.outputs:rgb>
                token outputs:surface
            }
            def Shader "T" {
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @../textures/t.png@
                float3 outputs:rgb
            }
        }
    """)
    files = {
        "scenes/shot.usda": layer(textwrap.dedent("""\
            def Camera "Cam" {
                double3 xformOp:translate = (0, 0, 4)
                uniform token[] xformOpOrder = ["xformOp:translate"]
                float focalLength = 20
            }
            def Xform "World" {
                custom asset notes = @../textures/missing.png@
                def "Prop" (references = @../assets/prop.usda@) {}
                def "Top" (references = @../top.usda@) {}
            }
        """), 'subLayers = [@../lib/lights.usda@]\nupAxis = "Y"'),
        "lib/lights.usda": light,
        "assets/prop.usda": layer(textwrap.dedent("""\
            def Xform "P" {
                def Mesh "M" (prepend apiSchemas = ["MaterialBindingAPI"]) {
                    rel material:binding = </P/Mat>
                    int[] faceVertexCounts = [3]
                    int[] faceVertexIndices = [0, 1, 2]
                    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
                }
                def "Extra" (references = @./parts/extra.usda@) {}
            """) + textwrap.indent(material, "    ") + "}\n", 'defaultPrim = "P"'),
        "assets/parts/extra.usda": layer(MESH.replace("(1, 0, 0), (0, 1, 0)", "(0, -1, 0), (-1, 0, 0)")
                                         .replace('"M"', '"E"'), 'defaultPrim = "E"'),
        "top.usda": layer(MESH.replace("(0, 0, 0), (1, 0, 0), (0, 1, 0)", "(-1, 0.2, -0.5), (-0.2, 0.2, -0.5), (-1, 1, -0.5)")
                          .replace('"M"', '"T"'), 'defaultPrim = "T"'),
    }
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    write_texture(root / "textures" / "t.png", rgb)
    return root / "scenes" / "shot.usda"


def test_gather_collects_the_project_as_it_lies_and_reports_what_is_missing(tmp_path):
    from tessera_renderer.usd.packing import gather

    shot = make_project(tmp_path / "proj")
    before = {p: p.read_bytes() for p in (tmp_path / "proj").rglob("*") if p.is_file()}
    pack = gather(shot)
    assert pack.root == tmp_path / "proj"   # the common ancestor, since ../ leaves scenes/
    assert pack.entry == "scenes/shot.usda"
    assert set(pack.files) == PROJECT_FILES
    assert all(pack.files[rel] == tmp_path / "proj" / rel for rel in PROJECT_FILES)
    assert pack.missing == ["../textures/missing.png (in shot.usda)"]
    assert pack.unportable == []
    assert pack.total_bytes == sum(len(b) for p, b in before.items())
    after = {p: p.read_bytes() for p in (tmp_path / "proj").rglob("*") if p.is_file()}
    assert after == before   # nothing of the user's is rewritten


def test_gather_reports_absolute_paths_and_uris_as_unportable(tmp_path):
    from tessera_renderer.usd.packing import gather

    make_project(tmp_path / "proj")
    scene = tmp_path / "proj" / "abs.usda"
    scene.write_text(layer(f'def "A" (references = @{tmp_path / "proj" / "top.usda"}@) {{}}\n'
                           'def "B" (references = @http://example.com/x.usda@) {}\n' + MESH))
    pack = gather(scene)
    assert set(pack.files) == {"abs.usda"}
    assert len(pack.unportable) == 2
    assert sorted(line.split(": ", 1)[1].split(";")[0] for line in pack.unportable) == ["a URI", "an absolute path"]


@pytest.mark.shared_scenes
@pytest.mark.parametrize("scene", SHARED, ids=[p.name for p in SHARED])
def test_gather_equals_usd_compute_all_dependencies(scene):
    """Our walk (the sandbox's, trusting ../) finds exactly the files USD's own
    UsdUtils.ComputeAllDependencies finds, and the same number of unresolved paths."""
    from pxr import UsdUtils

    from tessera_renderer.usd.packing import gather

    if not scene.exists():
        pytest.skip(f"{scene} is not on this machine")
    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(str(scene))
    theirs = {os.path.normpath(lyr.realPath) for lyr in layers} | {os.path.normpath(a) for a in assets}
    pack = gather(scene)
    assert {os.path.normpath(str(p)) for p in pack.files.values()} == theirs
    assert len(pack.missing) == len(unresolved)


def _render(args: list[str], capsys) -> tuple[int, str]:
    from tessera_cli.cli import main

    code = main(["render", *args, "--res", "24x16", "--spp", "2", "--seed", "3", "-q", "--threads", "1"])
    return code, capsys.readouterr().err


def test_local_render_trusts_the_users_files_and_sandbox_is_opt_in(tmp_path, capsys):
    """Default: references leaving the shot's folder resolve (the image equals the
    sandboxed render rooted at the project folder, so every layer and the texture were
    used). --sandbox: refused, naming the path."""
    from tessera_base import images

    shot = make_project(tmp_path / "proj")
    trusted, rooted, sandboxed = (tmp_path / f"{n}.exr" for n in ("trusted", "rooted", "sandboxed"))
    code, err = _render([str(shot), "-o", str(trusted)], capsys)
    assert code == 0, err
    code, err = _render([str(shot), "-o", str(rooted), "--root", str(tmp_path / "proj")], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(images.read_exr(trusted), images.read_exr(rooted))
    code, err = _render([str(shot), "-o", str(sandboxed), "--sandbox"], capsys)
    assert code == 2 and "../lib/lights.usda" in err and "outside the bundle" in err
    assert not sandboxed.exists()
    # The texture is read: another colour gives another image (a control for the equality).
    write_texture(tmp_path / "proj" / "textures" / "t.png", (30, 60, 200))
    code, err = _render([str(shot), "-o", str(rooted), "--root", str(tmp_path / "proj")], capsys)
    assert code == 0, err
    assert not np.array_equal(images.read_exr(trusted), images.read_exr(rooted))


def test_local_render_allows_absolute_paths_only_without_the_sandbox(tmp_path, capsys):
    from tessera_base import images

    make_project(tmp_path / "proj")
    absolute = tmp_path / "proj" / "scenes" / "abs.usda"
    absolute.write_text(layer(f'def "Top" (references = @{tmp_path / "proj" / "top.usda"}@) {{}}\n'))
    relative = tmp_path / "proj" / "scenes" / "rel.usda"
    relative.write_text(layer('def "Top" (references = @../top.usda@) {}\n'))
    code, err = _render([str(absolute), "-o", str(tmp_path / "a.exr")], capsys)
    assert code == 0, err
    code, err = _render([str(relative), "-o", str(tmp_path / "r.exr")], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(images.read_exr(tmp_path / "a.exr"), images.read_exr(tmp_path / "r.exr"))
    code, err = _render([str(absolute), "-o", str(tmp_path / "s.exr"), "--sandbox"], capsys)
    assert code == 2 and "is absolute" in err


@pytest.mark.shared_scenes
def test_local_render_of_the_mini_car_kit_as_usdview_opens_it(tmp_path, capsys):
    """vehicleVariants.usda references ../../../wheels/...: renders by default, equal to
    the render sandboxed at the kit's folder; refused with --sandbox."""
    from tessera_base import images

    scene = CAR_KIT / "assets" / "vehicles" / "vehicleVariants.usda"
    if not scene.exists():
        pytest.skip(f"{scene} is not on this machine")
    code, err = _render([str(scene), "-o", str(tmp_path / "t.exr")], capsys)
    assert code == 0, err
    code, err = _render([str(scene), "-o", str(tmp_path / "k.exr"), "--root", str(CAR_KIT)], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(images.read_exr(tmp_path / "t.exr"), images.read_exr(tmp_path / "k.exr"))
    code, err = _render([str(scene), "-o", str(tmp_path / "s.exr"), "--sandbox"], capsys)
    assert code == 2 and "wheelVariants.usda" in err


def test_gather_follows_the_textures_of_a_referenced_materialx_document(tmp_path):
    """A .mtlx look (the usdMtlx convention) travels with the image files its `filename`
    inputs name, relative to the document (fileprefix applied), as the translator reads them."""
    import MaterialX as mx

    from tessera_renderer.usd.packing import gather

    write_texture(tmp_path / "proj" / "tex" / "base.png", (10, 20, 30))
    doc = mx.createDocument()
    graph = doc.addNodeGraph("NG_look")
    graph.setFilePrefix("../tex/")
    for name in ("base", "gone"):
        graph.addNode("image", name, "color3").setInputValue("file", f"{name}.png", "filename")
    graph.addOutput("out", "color3").setConnectedNode(graph.getNode("base"))
    shader = doc.addNode("standard_surface", "SR_look", "surfaceshader")
    shader.addInput("base_color", "color3").setNodeGraphString("NG_look")
    doc.addMaterialNode("Look", shader)
    (tmp_path / "proj" / "looks").mkdir()
    mx.writeToXmlFile(doc, str(tmp_path / "proj" / "looks" / "look.mtlx"))
    shot = tmp_path / "proj" / "shots" / "a.usda"
    shot.parent.mkdir()
    shot.write_text(layer('def Material "Look" (references = @../looks/look.mtlx@</MaterialX/Materials/Look>) {}\n'
                          + MESH))
    pack = gather(shot)
    assert set(pack.files) == {"shots/a.usda", "looks/look.mtlx", "tex/base.png"}
    assert pack.missing == ["../tex/gone.png (in ../looks/look.mtlx)"]
