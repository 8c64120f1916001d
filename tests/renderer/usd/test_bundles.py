"""The bundle is a sandbox: crafted malicious or broken bundles each get the right error,
and no file outside the bundle is ever opened.

Every path a bundle tries to reach outside itself names a FIFO in `outside/`. Opening a
FIFO for reading blocks until a writer appears, so a loader that opened one would hang:
all bundles are loaded in one child process with a deadline, which reports each case as
it finishes. A hang fails the case that hung and every case after it."""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

MESH = textwrap.dedent("""\
    def Mesh "M" {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
""")


def layer(body: str = "", meta: str = "") -> str:
    return f"#usda 1.0\n({meta})\n{body}\n"


def texture_material(file: str) -> str:
    return MESH.replace("def Mesh \"M\" {", "def Mesh \"M\" (prepend apiSchemas = [\"MaterialBindingAPI\"]) {\n"
                        "    rel material:binding = </Mat>") + textwrap.dedent(f"""\
        def Material "Mat" {{
            token outputs:surface.connect = </Mat/S.outputs:surface>
            def Shader "S" {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </Mat/T.outputs:rgb>
                token outputs:surface
            }}
            def Shader "T" {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @{file}@
                float3 outputs:rgb
            }}
        }}
    """)


def write_zip(path: Path, members: list[tuple], **kw) -> Path:
    """members: (name, bytes) or (ZipInfo, bytes)."""
    with zipfile.ZipFile(path, "w", compression=kw.get("compression", zipfile.ZIP_DEFLATED)) as zf:
        for name, data in members:
            zf.writestr(name, data)
    return path


def symlink_info(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name)
    info.create_system = 3
    info.external_attr = (stat.S_IFLNK | 0o777) << 16
    return info


# name -> (builder(tmp, outside) -> (path, options), expectation)
# expectation: ("error", [substrings]) or ("warning", [substrings]) or ("ok", [])
CASES: dict[str, tuple] = {}


def case(name, kind, *needles):
    def deco(fn):
        CASES[name] = (fn, (kind, list(needles)))
        return fn
    return deco


@case("sublayer_escapes_with_dotdot", "error", "../outside/secret.usda", "outside the bundle")
def _(b: Path, out: Path):
    (b / "scene.usda").write_text(layer(MESH, "subLayers = [@../outside/secret.usda@]"))
    return b / "scene.usda", {}


@case("reference_absolute_path", "error", "absolute", "secret.usda")
def _(b, out):
    (b / "scene.usda").write_text(layer(f'def "R" (references = @{out}/secret.usda@) {{}}\n' + MESH))
    return b / "scene.usda", {}


@case("payload_escapes_deep", "error", "../../", "outside the bundle")
def _(b, out):
    (b / "sub").mkdir()
    (b / "sub" / "scene.usda").write_text(layer('def "P" (payload = @../../outside/secret.usda@) {}\n' + MESH))
    return b / "sub" / "scene.usda", {"root": str(b)}


@case("texture_absolute_to_etc_passwd", "error", "/etc/passwd", "absolute")
def _(b, out):
    (b / "scene.usda").write_text(layer(texture_material("/etc/passwd")))
    return b / "scene.usda", {}


@case("texture_absolute_to_outside_fifo", "error", "passwd.png", "absolute")
def _(b, out):
    (b / "scene.usda").write_text(layer(texture_material(f"{out}/passwd.png")))
    return b / "scene.usda", {}


@case("texture_escapes_with_dotdot", "error", "../outside/passwd.png", "outside the bundle")
def _(b, out):
    (b / "scene.usda").write_text(layer(texture_material("../outside/passwd.png")))
    return b / "scene.usda", {}


@case("reference_is_a_uri", "error", "https://example.com/evil.usda", "URI")
def _(b, out):
    (b / "scene.usda").write_text(layer('def "R" (references = @https://example.com/evil.usda@) {}\n' + MESH))
    return b / "scene.usda", {}


@case("texture_file_uri", "error", "file:///etc/passwd", "URI")
def _(b, out):
    (b / "scene.usda").write_text(layer(texture_material("file:///etc/passwd")))
    return b / "scene.usda", {}


@case("search_path_lookup", "error", "secret.usda", "search-path lookups are not allowed")
def _(b, out):
    # Not beside the layer: only a search path (or the working directory) could find it.
    (b / "scene.usda").write_text(layer('def "R" (references = @secret.usda@) {}\n' + MESH))
    return b / "scene.usda", {}


def _names_itself(prim_meta: str = "") -> str:
    """A prim whose assetInfo names its asset's file (`identifier = @Teapot.usd@`, as the
    USD working group's teapot does) in a layer stored under another name, as an upload is."""
    return ('def Xform "Teapot" (\n    assetInfo = { asset identifier = @Teapot.usd@ }\n'
            f'{prim_meta})\n{{\n{MESH}}}\n')


@case("asset_info_identifier_names_itself", "ok")
def _(b, out):
    (b / "scene.usda").write_text(layer(_names_itself()))
    return b / "scene.usda", {}


@case("asset_info_identifier_and_a_missing_payload", "error",
      "layer './Teapot_Payload.usd' is not in the bundle")
def _(b, out):
    # The payload is what is missing, and the message must name it, not the identifier.
    (b / "scene.usda").write_text(layer(_names_itself("    prepend payload = @./Teapot_Payload.usd@\n")))
    return b / "scene.usda", {}


@case("asset_info_identifier_also_a_clip", "error", "layer 'Teapot.usd' is not in the bundle",
      "search-path lookups are not allowed")
def _(b, out):
    # Named as an identifier AND as a value clip, which USD does open: still refused.
    clips = ('    clips = { dictionary default = { asset[] assetPaths = [@Teapot.usd@]\n'
             '        string primPath = "/Clip"\n        double2[] active = [(0, 0)] } }\n')
    (b / "scene.usda").write_text(layer(_names_itself(clips)))
    return b / "scene.usda", {}


@case("value_clip_escapes", "error", "../outside/secret.usda")
def _(b, out):
    (b / "scene.usda").write_text(layer(textwrap.dedent("""\
        def Xform "Clipped" (
            clips = {
                dictionary default = {
                    asset[] assetPaths = [@../outside/secret.usda@]
                    asset manifestAssetPath = @./manifest.usda@
                    string primPath = "/Clip"
                    double2[] active = [(0, 0)]
                }
            }
        ) {}
    """) + MESH))
    (b / "manifest.usda").write_text(layer())
    return b / "scene.usda", {}


@case("symlink_on_disk_leads_outside", "error", "link.png", "symlink")
def _(b, out):
    os.symlink(out / "passwd.png", b / "link.png")
    (b / "scene.usda").write_text(layer(texture_material("./link.png")))
    return b / "scene.usda", {}


@case("zip_member_with_dotdot", "error", "../evil.usda", "escapes")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(MESH)), ("../evil.usda", layer())]), {}


@case("zip_member_absolute", "error", "/tmp/evil.usda", "absolute")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(MESH)), ("/tmp/evil.usda", layer())]), {}


@case("zip_member_symlink", "error", "tex.png", "symlink")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(texture_material("./tex.png"))),
                                        (symlink_info("tex.png"), str(out / "passwd.png"))]), {}


@case("zip_bomb_ratio", "error", "zeros.bin", "zip bomb")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(MESH)), ("zeros.bin", bytes(20 << 20))]), {}


@case("zip_over_unpacked_limit", "error", "unpacks to more than 4096 bytes")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(MESH)), ("data.bin", os.urandom(8192))],
                     compression=zipfile.ZIP_STORED), {"limits": {"unpacked_bytes": 4096}}


@case("zip_member_lies_about_its_size", "error", "data.bin")
def _(b, out):
    path = write_zip(b / "bundle.zip", [("scene.usda", layer(MESH)), ("data.bin", os.urandom(10000))],
                     compression=zipfile.ZIP_STORED)
    raw = bytearray(path.read_bytes())
    # Central directory entry of data.bin: declare 10 bytes where 10,000 follow.
    at = raw.index(b"PK\x01\x02", raw.index(b"PK\x01\x02") + 4)
    raw[at + 24:at + 28] = (10).to_bytes(4, "little")
    path.write_bytes(bytes(raw))
    return path, {}


@case("package_relative_path_escapes_its_package", "error", "pkg.usdz[../../outside/secret.usda]",
      "not a valid path inside a package")
def _(b, out):
    write_zip(b / "pkg.usdz", [("inner.usda", layer(MESH))], compression=zipfile.ZIP_STORED)
    (b / "scene.usda").write_text(layer('def "R" (references = @./pkg.usdz[../../outside/secret.usda]@) {}\n'))
    return b / "scene.usda", {}


@case("valid_reference_into_a_nested_package", "ok")
def _(b, out):
    write_zip(b / "pkg.usdz", [("inner.usda", layer(MESH, 'defaultPrim = "M"'))], compression=zipfile.ZIP_STORED)
    (b / "scene.usda").write_text(layer('def "R" (references = @./pkg.usdz[inner.usda]@) {}\n'
                                        + texture_material("./t.png").replace(MESH, "")))
    import numpy as np
    import OpenImageIO as oiio
    oiio.ImageBuf(np.full((2, 2, 3), 9, np.uint8)).write(str(b / "t.png"))
    return b / "scene.usda", {}


@case("zip_too_many_files", "error", "more than the limit of 5 files")
def _(b, out):
    return write_zip(b / "bundle.zip", [("scene.usda", layer(MESH))] +
                     [(f"f{i}.txt", b"x") for i in range(8)]), {"limits": {"files": 5}}


@case("zip_not_a_zip", "error", "not a readable zip archive")
def _(b, out):
    (b / "bundle.zip").write_bytes(os.urandom(4096))
    return b / "bundle.zip", {}


@case("zip_without_usd", "error", "no USD layer")
def _(b, out):
    return write_zip(b / "bundle.zip", [("readme.txt", b"hello")]), {}


@case("usdz_reference_escapes_package", "error", "../outside/secret.usda", "outside the bundle")
def _(b, out):
    return write_zip(b / "pkg.usdz", [("scene.usda", layer('def "R" (references = @../outside/secret.usda@) {}\n' + MESH))],
                     compression=zipfile.ZIP_STORED), {}


@case("zero_byte_file", "error", "empty")
def _(b, out):
    (b / "scene.usdc").write_bytes(b"")
    return b / "scene.usdc", {}


@case("binary_garbage_usdc", "error", "cannot read")
def _(b, out):
    (b / "scene.usdc").write_bytes(b"PXR-USDC" + os.urandom(2000))
    return b / "scene.usdc", {}


@case("empty_sublayer_file", "error", "empty.usda", "empty file")
def _(b, out):
    (b / "empty.usda").write_bytes(b"")
    (b / "scene.usda").write_text(layer(MESH, "subLayers = [@./empty.usda@]"))
    return b / "scene.usda", {}


@case("cyclic_references", "error", "cycle")
def _(b, out):
    (b / "scene.usda").write_text(layer('def "A" (references = @./other.usda@</B>) {}\n' + MESH))
    (b / "other.usda").write_text(layer('def "B" (references = @./scene.usda@</A>) {}'))
    return b / "scene.usda", {}


@case("nan_and_inf_points", "warning", "/M", "NaN/Inf")
def _(b, out):
    (b / "scene.usda").write_text(layer(MESH.replace("(1, 0, 0)", "(inf, 0, 0)") +
                                        MESH.replace('"M"', '"N"').replace("(0, 1, 0)", "(nan, 1, 0)")))
    return b / "scene.usda", {}


@case("out_of_range_indices", "error", "/M", "reference vertex 9")
def _(b, out):
    (b / "scene.usda").write_text(layer(MESH.replace("[0, 1, 2]", "[0, 1, 9]")))
    return b / "scene.usda", {}


@case("negative_face_counts", "error", "/M", "faceVertexCounts")
def _(b, out):
    (b / "scene.usda").write_text(layer(MESH.replace("int[] faceVertexCounts = [3]",
                                                     "int[] faceVertexCounts = [-3, 6]")))
    return b / "scene.usda", {}


@case("point_instancer_bad_proto_index", "error", "/PI", "protoIndices")
def _(b, out):
    (b / "scene.usda").write_text(layer(textwrap.dedent("""\
        def PointInstancer "PI" {
            point3f[] positions = [(0, 0, 0), (1, 0, 0)]
            int[] protoIndices = [0, 5]
            rel prototypes = </PI/Protos/M>
            def Scope "Protos" {
    """) + textwrap.indent(MESH, "        ") + "    }\n}\n"))
    return b / "scene.usda", {}


@case("missing_texture_warns_and_renders", "warning", "nothere.png", "missing")
def _(b, out):
    (b / "scene.usda").write_text(layer(texture_material("./nothere.png")))
    return b / "scene.usda", {}


@case("missing_referenced_layer", "error", "./gone.usda", "not in the bundle")
def _(b, out):
    (b / "scene.usda").write_text(layer('def "R" (references = @./gone.usda@) {}\n' + MESH))
    return b / "scene.usda", {}


@case("prim_limit", "error", "more than 3 prims")
def _(b, out):
    (b / "scene.usda").write_text(layer("".join(f'def Xform "X{i}" {{}}\n' for i in range(10)) + MESH))
    return b / "scene.usda", {"limits": {"prims": 3}}


@case("triangle_limit", "error", "/M", "more than 0 triangles")
def _(b, out):
    (b / "scene.usda").write_text(layer(MESH))
    return b / "scene.usda", {"limits": {"triangles": 0}}


@case("texture_resolution_limit", "error", "big.png", "more than the limit of 100 pixels")
def _(b, out):
    import numpy as np
    import OpenImageIO as oiio
    oiio.ImageBuf(np.zeros((64, 64, 3), np.uint8)).write(str(b / "big.png"))
    (b / "scene.usda").write_text(layer(texture_material("./big.png")))
    return b / "scene.usda", {"limits": {"texture_pixels": 100}}


@case("valid_zip_bundle_with_texture", "ok")
def _(b, out):
    import numpy as np
    import OpenImageIO as oiio
    oiio.ImageBuf(np.full((4, 4, 3), 200, np.uint8)).write(str(b / "t.png"))
    return write_zip(b / "bundle.zip", [("scene.usda", layer(texture_material("textures/t.png"))),
                                        ("textures/t.png", (b / "t.png").read_bytes())]), {}


CHILD = r"""
import json, sys
import numpy as np
from tessera_renderer import Scene, SceneError, load_scene
from tessera_renderer.usd.bundle import Limits, open_bundle
from tessera_renderer.usd import translate_stage
for line in sys.stdin:
    job = json.loads(line)
    out = {"case": job["case"]}
    try:
        opts = job["options"]
        if "limits" in opts:
            bundle = open_bundle(job["path"], root=opts.get("root"), limits=Limits(**opts["limits"]))
            scene = Scene(translate_stage(job["path"], bundle=bundle))
        else:
            scene = load_scene(job["path"], root=opts.get("root"))
        img = scene.render_tile(0, 0, 4, 4, width=4, height=4, spp=1)
        out.update(ok=True, warnings=scene.warnings, finite=bool(np.isfinite(img).all()),
                   textures=[t["file"] for t in scene.data.textures])
    except SceneError as exc:
        out.update(ok=False, error=str(exc), kind="SceneError")
    except Exception as exc:
        out.update(ok=False, error=f"{type(exc).__name__}: {exc}", kind=type(exc).__name__)
    print(json.dumps(out), flush=True)
"""


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    base = tmp_path_factory.mktemp("bundles")
    outside = base / "outside"
    outside.mkdir()
    for name in ("secret.usda", "passwd.png", "evil.usda"):
        os.mkfifo(outside / name)
    jobs = []
    for name, (build, _) in CASES.items():
        bdir = base / name
        bdir.mkdir()
        path, options = build(bdir, outside)
        jobs.append({"case": name, "path": str(path), "options": options})
    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, cwd=str(outside))
    try:
        stdout, _ = proc.communicate("".join(json.dumps(j) + "\n" for j in jobs), timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, _ = proc.communicate()
    results = {}
    for line in stdout.splitlines():
        if line.startswith("{"):
            r = json.loads(line)
            results[r["case"]] = r
    # The FIFOs are still FIFOs nobody wrote through (a sanity check of the canary).
    assert all(stat.S_ISFIFO(os.stat(outside / n).st_mode) for n in ("secret.usda", "passwd.png"))
    return results


def test_there_are_at_least_twenty_malicious_or_broken_bundles():
    assert sum(1 for _, (kind, _) in CASES.values() if kind != "ok") >= 20


@pytest.mark.parametrize("name", list(CASES))
def test_bundle_gets_the_right_answer_without_reading_outside(outcomes, name):
    kind, needles = CASES[name][1]
    assert name in outcomes, (f"{name}: the loader never answered: it blocked, most likely on "
                              f"opening a FIFO outside the bundle (or crashed)")
    r = outcomes[name]
    if kind == "error":
        assert not r["ok"], f"{name}: loaded but should have been rejected: {r}"
        assert r["kind"] == "SceneError", r
        for needle in needles:
            assert needle in r["error"], f"{name}: {needle!r} not in {r['error']!r}"
    else:
        assert r["ok"], f"{name}: {r.get('error')}"
        assert r["finite"]
        text = " | ".join(r["warnings"])
        for needle in needles:
            assert needle in text, f"{name}: {needle!r} not in warnings {text!r}"
    if name == "valid_zip_bundle_with_texture":
        assert r["textures"] and all("tessera-bundle-" in t for t in r["textures"]), r


def test_unpacked_bundles_are_removed_with_their_scene(tmp_path):
    import gc

    from tessera_renderer import load_scene
    zpath = write_zip(tmp_path / "b.zip", [("scene.usda", layer(MESH))])
    scene = load_scene(zpath)
    root = scene.data._bundle.root
    assert root.is_dir() and root != tmp_path
    del scene
    gc.collect()
    assert not root.exists()
