"""UsdLux light linking and shadow linking (collection:lightLink, collection:shadowLink),
authored with UsdLux's collection API as tools write it, against closed forms.

Every scene is a Lambertian floor (albedo 0.5) seen straight down through a camera whose
4x4 pixels cover about a millimetre around the origin: each pixel reads the floor's
radiance there, 0.5 E / pi for irradiance E. Rect lights' irradiance comes from Lambert's
polygon formula, point lights' from the inverse square law."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdLux

from tessera_base import integrators
from tessera_renderer import Scene, load_scene
from tessera_renderer.usd import translate_stage

from usd_fixtures import add_camera, add_mesh, add_render_settings, new_stage

ALBEDO = 0.5
RECT_RADIANCE = 4.0


def _floor_stage(tmp_path, name):
    stage = new_stage(tmp_path / f"{name}.usda")
    ground = add_mesh(stage, "/World/Ground", [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)], [4],
                      [0, 1, 2, 3])
    ground.CreateDisplayColorAttr([Gf.Vec3f(ALBEDO, ALBEDO, ALBEDO)])
    # Below every light and occluder: it sees only the floor.
    cam = add_camera(stage, "/Cam", (0, 0.5, 0), focal=1000.0, haperture=1.0, vaperture=1.0)
    cam.AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (4, 4))
    return stage


def _rect_light(stage, path, center, size=1.0):
    """A RectLight of radiance RECT_RADIANCE facing down (its -Z turned to -Y)."""
    light = UsdLux.RectLight.Define(stage, path)
    light.AddTranslateOp().Set(Gf.Vec3d(*center))
    light.AddRotateXOp().Set(-90.0)
    light.CreateWidthAttr(size)
    light.CreateHeightAttr(size)
    light.CreateIntensityAttr(RECT_RADIANCE)
    return light


def _rect_corners(center, size=1.0):
    """The corners of _rect_light's rectangle, in order around it (it lies in a y plane)."""
    cx, cy, cz = center
    h = size / 2
    return np.array([(cx - h, cy, cz - h), (cx + h, cy, cz - h), (cx + h, cy, cz + h), (cx - h, cy, cz + h)])


def _polygon_irradiance(corners, radiance, p=(0.0, 0.0, 0.0), n=(0.0, 1.0, 0.0)):
    """Lambert's formula: E = L / 2 |sum_i angle_i (n . unit(v_i x v_i+1))| for a
    uniformly emitting polygon wholly above the receiver's plane."""
    v = np.asarray(corners, float) - np.asarray(p, float)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(v)):
        a, b = v[i], v[(i + 1) % len(v)]
        c = np.cross(a, b)
        total += math.acos(np.clip(a @ b, -1, 1)) * (np.asarray(n) @ (c / np.linalg.norm(c)))
    return radiance / 2 * abs(total)


def _radiance(irradiance):
    return ALBEDO * irradiance / math.pi


def _render(path_or_stage, spp=256, light_selection="auto", integrator="path"):
    path = path_or_stage if isinstance(path_or_stage, str) else _save(path_or_stage)
    if light_selection == "auto":
        scene = load_scene(path)
    else:
        scene = Scene(translate_stage(path, instancing="auto"), light_selection=light_selection)
    img = scene.render_tile(0, 0, 4, 4, spp=spp, max_depth=1, integrator=integrator)[..., :3]
    return scene, float(img.mean())


def _save(stage):
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


KEY, FILL = (-1.0, 2.0, 0.0), (1.5, 2.0, 0.0)


@pytest.mark.parametrize("light_selection", ["power", "bvh"])
def test_a_light_whose_link_excludes_the_floor_adds_nothing_to_it(tmp_path, light_selection):
    """Two rect lights; the key's light link excludes the floor: the floor reads the fill's
    closed form alone, to 2 %. BSDF-sampled rays from the floor still hit the key (its
    emission must count for nothing there, whatever the MIS weights), and the key is still
    chosen by light sampling (those samples must add nothing): either mistake leaves the
    key's share, 41 % of the fill's here, in the image. Negative control: the fill's value
    with 2 % of the key's added fails the same check. Both light selectors (the power
    table and the light BVH) reject the key alike."""
    stage = _floor_stage(tmp_path, "light_link")
    key = _rect_light(stage, "/World/Key", KEY)
    _rect_light(stage, "/World/Fill", FILL)
    UsdLux.LightAPI(key).GetLightLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Ground")
    scene, got = _render(stage, light_selection=light_selection)
    assert scene.num_linked_lights == 1
    e_key = _polygon_irradiance(_rect_corners(KEY), RECT_RADIANCE)
    e_fill = _polygon_irradiance(_rect_corners(FILL), RECT_RADIANCE)
    assert e_key > 0.4 * e_fill  # the key's share is far above the tolerance
    expected = _radiance(e_fill)
    assert got == pytest.approx(expected, rel=0.02)
    # Negative control: 2 % of the key's light more than the fill's must fail the check.
    assert _radiance(e_fill + 0.1 * e_fill) != pytest.approx(expected, rel=0.02)
    assert _radiance(e_fill + e_key) != pytest.approx(expected, rel=0.02)


def test_without_links_both_lights_reach_the_floor(tmp_path):
    """The same rig with default collections: the sum of both closed forms (what the test
    above would read had linking been ignored)."""
    stage = _floor_stage(tmp_path, "no_link")
    _rect_light(stage, "/World/Key", KEY)
    _rect_light(stage, "/World/Fill", FILL)
    scene, got = _render(stage)
    assert scene.num_linked_lights == 0
    e = _polygon_irradiance(_rect_corners(KEY), RECT_RADIANCE) + _polygon_irradiance(_rect_corners(FILL),
                                                                                      RECT_RADIANCE)
    assert got == pytest.approx(_radiance(e), rel=0.02)


def test_point_lights_linked_by_include_root_off_as_karma_writes_it(tmp_path):
    """Houdini's light linker writes includeRoot = 0 and the lit prims as includes. The
    key point light includes only a prim elsewhere: the floor reads the fill's inverse
    square law exactly (point lights have no variance here; 0.1 %)."""
    path = tmp_path / "karma.usda"
    path.write_text('''#usda 1.0
(
    upAxis = "Y"
    renderSettingsPrimPath = "/Render/Settings"
)
def Xform "World" {
    def Mesh "Ground" {
        point3f[] points = [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        uniform token subdivisionScheme = "none"
        color3f[] primvars:displayColor = [(0.5, 0.5, 0.5)]
    }
    def Sphere "Prop" {
        double radius = 0.1
        double3 xformOp:translate = (20, 0.1, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def SphereLight "Key" (
        prepend apiSchemas = ["CollectionAPI:lightLink", "CollectionAPI:shadowLink"]
    ) {
        bool treatAsPoint = 1
        bool inputs:normalize = 1
        float inputs:intensity = 40
        uniform bool collection:lightLink:includeRoot = 0
        prepend rel collection:lightLink:includes = </World/Prop>
        double3 xformOp:translate = (0, 2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def SphereLight "Fill" {
        bool treatAsPoint = 1
        bool inputs:normalize = 1
        float inputs:intensity = 16
        double3 xformOp:translate = (0, 1, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
def Camera "Cam" {
    float focalLength = 1000
    float horizontalAperture = 1
    float verticalAperture = 1
    double3 xformOp:translate = (0, 0.5, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}
def Scope "Render" {
    def RenderSettings "Settings" {
        int2 resolution = (4, 4)
        rel camera = </Cam>
    }
}
''')
    scene, got = _render(str(path), spp=16)
    assert scene.num_linked_lights == 1
    d2 = 1.0 ** 2 + 0.5 ** 2
    fill = (16 / 4) * (1.0 / math.sqrt(d2)) / d2  # I cos / d^2, I = intensity / 4 (normalize)
    key = (40 / 4) / 2.0 ** 2
    assert got == pytest.approx(_radiance(fill), rel=1e-3)
    assert _radiance(fill + key) != pytest.approx(_radiance(fill), rel=0.02)  # the key, had it lit the floor


def test_excluding_a_parent_excludes_its_children(tmp_path):
    """Collections expand to descendants (expandPrims, the fallback rule): excluding
    /World excludes the floor under it, which then gets a link group of its own."""
    stage = _floor_stage(tmp_path, "parent")
    key = _rect_light(stage, "/Lights/Key", KEY)
    UsdLux.LightAPI(key).GetLightLinkCollectionAPI().GetExcludesRel().AddTarget("/World")
    data = translate_stage(_save(stage))
    links = data.light_links
    assert links["illuminates"].shape[0] == 1
    ground_group = links["material_group"][data.triangle_material[0]]
    assert ground_group != 0 and links["illuminates"][0, ground_group] == 0
    assert links["shadows"][0, ground_group] == 1
    assert (links["material_light"] >= 0).sum() == 1  # the key's own row


OCCLUDER_Y = 1.0
SHADOW_LIGHT = (0.0, 2.0, 0.0)


def _shadow_rig(tmp_path, name, exclude: bool):
    """A rect light straight above the origin, a 3 x 3 occluder between it and the floor."""
    stage = _floor_stage(tmp_path, name)
    light = _rect_light(stage, "/World/Light", SHADOW_LIGHT)
    add_mesh(stage, "/World/Occluder", [(-1.5, OCCLUDER_Y, -1.5), (1.5, OCCLUDER_Y, -1.5), (1.5, OCCLUDER_Y, 1.5),
                                        (-1.5, OCCLUDER_Y, 1.5)], [4], [0, 1, 2, 3], double_sided=True)
    if exclude:
        shadow = UsdLux.LightAPI(light).GetShadowLinkCollectionAPI()
        shadow.GetExcludesRel().AddTarget("/World/Occluder")
    return stage


@pytest.mark.parametrize("light_selection", ["power", "bvh"])
def test_a_shadow_link_excluding_the_occluder_removes_its_shadow(tmp_path, light_selection):
    """The occluder's shadow covers the floor's view of the light entirely; excluded from
    the light's shadow link, it lets the light's full closed-form irradiance through, to
    2 %. The occluder still stops BSDF-sampled rays, so path must estimate this light by
    light sampling alone: weighted by MIS as usual it would read only the light-sampling
    share (negative control: 98 % of the closed form fails the check, and so does the
    shadowed floor's 0)."""
    scene, got = _render(_shadow_rig(tmp_path, f"shadow_link_{light_selection}", True),
                         light_selection=light_selection)
    assert scene.num_linked_lights == 1
    expected = _radiance(_polygon_irradiance(_rect_corners(SHADOW_LIGHT), RECT_RADIANCE))
    assert got == pytest.approx(expected, rel=0.02)
    assert 0.98 * 0.98 * expected != pytest.approx(expected, rel=0.02)


def test_the_occluder_shadows_the_floor_without_a_shadow_link(tmp_path):
    """The control rig: with the default shadow link the floor under the occluder is black."""
    scene, got = _render(_shadow_rig(tmp_path, "shadowed", False))
    assert scene.num_linked_lights == 0
    assert got == 0.0


def test_integrators_that_ignore_links_say_so_once(tmp_path):
    scene, _ = _render(_shadow_rig(tmp_path, "warned", True), spp=1)
    warned = integrators.scene_warnings("bdpt", linked_lights=scene.num_linked_lights)
    assert len(warned) == 1 and "bdpt" in warned[0] and "path" in warned[0] and "local" in warned[0]
    assert integrators.scene_warnings("path", linked_lights=1) == []
    assert integrators.scene_warnings("local", linked_lights=1) == []
    assert integrators.scene_warnings("bdpt", linked_lights=0) == []
    assert len(integrators.scene_warnings("path", linked_lights=1, media=True)) == 1


def test_local_honours_links_as_path_does(tmp_path):
    scene, got = _render(_shadow_rig(tmp_path, "local", True), integrator="local")
    expected = _radiance(_polygon_irradiance(_rect_corners(SHADOW_LIGHT), RECT_RADIANCE))
    assert got == pytest.approx(expected, rel=0.02)


def test_links_survive_the_farm_blob(tmp_path):
    """The farm renders from the translated blob: the same links, the same image."""
    from tessera_renderer.scene_blob import scene_from_blob, translate_to_blob

    path = _save(_shadow_rig(tmp_path, "blob", True))
    local = load_scene(path)
    remote = scene_from_blob(translate_to_blob(path))
    assert remote.num_linked_lights == local.num_linked_lights == 1
    a = local.render_tile(0, 0, 4, 4, spp=8, max_depth=1)
    b = remote.render_tile(0, 0, 4, 4, spp=8, max_depth=1)
    assert np.array_equal(a, b)


def test_native_instances_linked_differently_get_prototypes_of_their_own(tmp_path):
    """Two instances of one prototype; the key's link excludes one of them. Each keeps its
    own link group, so the instanced render equals the flattened one bit for bit."""
    path = tmp_path / "instances.usda"
    path.write_text('''#usda 1.0
(
    upAxis = "Y"
)
class Xform "Tile" {
    def Mesh "Quad" {
        point3f[] points = [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        uniform token subdivisionScheme = "none"
        color3f[] primvars:displayColor = [(0.5, 0.5, 0.5)]
    }
}
def Xform "World" {
    def Xform "A" (
        instanceable = true
        references = </Tile>
    ) {
        double3 xformOp:translate = (-1, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Xform "B" (
        instanceable = true
        references = </Tile>
    ) {
        double3 xformOp:translate = (1, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def SphereLight "Key" {
        bool treatAsPoint = 1
        float inputs:intensity = 10
        rel collection:lightLink:excludes = </World/A>
        double3 xformOp:translate = (0, 2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
def Camera "Cam" {
    double3 xformOp:translate = (0, 6, 0)
    float xformOp:rotateX = -90
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
}
''')
    inst = translate_stage(str(path), instancing="auto")
    assert len(inst.prototypes) == 2 and len(inst.instances) == 2
    groups = {int(inst.light_links["material_group"][p["triangle_material"][0]]) for p in inst.prototypes}
    assert len(groups) == 2
    flat = load_scene(str(path), instancing="flatten")
    instanced = load_scene(str(path), instancing="auto")
    a = flat.render_tile(0, 0, 16, 16, width=16, height=16, spp=4, max_depth=1)
    b = instanced.render_tile(0, 0, 16, 16, width=16, height=16, spp=4, max_depth=1)
    assert np.abs(a - b).max() < 1e-5
    # The excluded tile (left half of the image) is black, the other lit.
    assert a[2:14, :7, :3].max() == 0.0 and a[2:14, 9:14, :3].min() > 0.0
