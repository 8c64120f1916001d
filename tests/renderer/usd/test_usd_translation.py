"""USD -> flat arrays: geometry, materials, lights, camera and errors."""
import functools
import math

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from tessera_renderer import SceneError, load_scene
from tessera_renderer.usd.meshes import _triangulate_fan
from tessera_renderer.usd import translate_stage as _translate_stage
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

# These tests read what the translation put where: world coordinates, not the
# camera-relative ones a render uses (test_stability.py tests those).
translate_stage = functools.partial(_translate_stage, camera_relative=False)


def triangle_areas(data):
    p = data.positions[data.indices]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def test_fan_triangulation_of_mixed_polygons():
    counts = np.array([3, 4, 5, 2, 6])
    idx = np.arange(counts.sum())
    tris = _triangulate_fan(counts, idx)
    assert len(tris) == 1 + 2 + 3 + 0 + 4
    # every triangle of a face starts at the face's first vertex and stays inside the face
    assert tris[0].tolist() == [0, 1, 2]
    assert tris[1].tolist() == [3, 4, 5] and tris[2].tolist() == [3, 5, 6]
    assert tris[-1].tolist() == [14, 18, 19]


def test_polygons_keep_their_area_and_transforms_apply(tmp_path):
    stage = new_stage(tmp_path / "s.usda")
    xf = UsdGeom.Xform.Define(stage, "/A")
    xf.AddTranslateOp().Set(Gf.Vec3d(10, 0, 0))
    xf.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    # a unit square and a regular hexagon of side 1 in the XY plane
    hexagon = [(math.cos(k * math.pi / 3), math.sin(k * math.pi / 3), 0) for k in range(6)]
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)] + hexagon
    add_mesh(stage, "/A/M", pts, [4, 6], list(range(10)))
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "s.usda"))
    assert data.indices.shape == (2 + 4, 3)
    expected_area = 4 * (1.0 + 3 * math.sqrt(3) / 2)  # scale 2 -> area x4
    assert triangle_areas(data).sum() == pytest.approx(expected_area, rel=1e-5)
    assert data.positions[:, 0].min() == pytest.approx(10 - 2)  # translated after scaling


def test_left_handed_orientation_flips_the_emitting_side(tmp_path):
    def render_emitter(orientation):
        path = tmp_path / f"{orientation}.usda"
        stage = new_stage(path)
        light = add_material(stage, "/L", (0, 0, 0), (1, 1, 1))
        # counter-clockwise seen from +z: faces the camera (at +z) when rightHanded
        mesh = add_mesh(stage, "/Q", [(-9, -9, -1), (9, -9, -1), (9, 9, -1), (-9, 9, -1)], [4], [0, 1, 2, 3], light)
        mesh.CreateOrientationAttr(orientation)
        add_render_settings(stage, add_camera(stage, "/C", (0, 0, 1)), (4, 4))
        stage.GetRootLayer().Save()
        return load_scene(path).render_tile(0, 0, 4, 4, spp=1)[..., :3].mean()

    assert render_emitter(UsdGeom.Tokens.rightHanded) == 1.0
    assert render_emitter(UsdGeom.Tokens.leftHanded) == 0.0


def test_materials_display_color_and_defaults(tmp_path):
    stage = new_stage(tmp_path / "m.usda")
    red = add_material(stage, "/Looks/Red", (0.8, 0.1, 0.1))
    add_mesh(stage, "/Bound", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2], red)
    plain = add_mesh(stage, "/Plain", [(0, 0, 1), (1, 0, 1), (0, 1, 1)], [3], [0, 1, 2])
    colored = add_mesh(stage, "/Colored", [(0, 0, 2), (1, 0, 2), (0, 1, 2)], [3], [0, 1, 2])
    colored.CreateDisplayColorAttr([Gf.Vec3f(0.2, 0.3, 0.4)])
    assert plain
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "m.usda"))
    albedo = data.albedo[data.triangle_material]
    np.testing.assert_allclose(albedo[0], (0.8, 0.1, 0.1), rtol=1e-6)
    np.testing.assert_allclose(albedo[1], (0.18, 0.18, 0.18), rtol=1e-6)  # UsdPreviewSurface default
    np.testing.assert_allclose(albedo[2], (0.2, 0.3, 0.4), rtol=1e-6)


def test_invisible_and_guide_prims_are_skipped_and_unsupported_ones_warned(tmp_path):
    stage = new_stage(tmp_path / "v.usda")
    tri = ([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    add_mesh(stage, "/Visible", *tri)
    hidden = UsdGeom.Xform.Define(stage, "/Hidden")
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    add_mesh(stage, "/Hidden/Child", *tri)
    guide = add_mesh(stage, "/Guide", *tri)
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    UsdGeom.NurbsCurves.Define(stage, "/Curve")
    UsdGeom.NurbsCurves.Define(stage, "/Curve2")
    UsdGeom.HermiteCurves.Define(stage, "/Hermite")
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "v.usda"))
    assert len(data.indices) == 1
    text = " | ".join(data.warnings)
    assert "2 NurbsCurves prims not supported yet" in text
    assert "1 HermiteCurves prim not supported yet" in text
    assert "no camera" in text


def test_render_settings_give_resolution_and_camera(tmp_path):
    stage = new_stage(tmp_path / "r.usda")
    add_camera(stage, "/CamA", (0, 0, 5))
    cam_b = add_camera(stage, "/CamB", (1, 2, 3), focal=35.0, haperture=25.0, vaperture=25.0)
    add_render_settings(stage, cam_b, (320, 200))
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "r.usda"))
    assert data.resolution == (320, 200) and data.resolution_from_stage
    assert data.camera.source == "/CamB"
    assert data.camera.origin == pytest.approx((1, 2, 3))
    assert data.camera.forward == pytest.approx((0, 0, -1))
    # square aperture on a wide image: the horizontal angle is expanded
    tan_w, tan_h = data.camera.tan_half_angles(320, 200)
    assert tan_h == pytest.approx(12.5 / 35.0)
    assert tan_w == pytest.approx(12.5 / 35.0 * 320 / 200)


def test_cornell_example_translates_cleanly(cornell_path):
    scene = load_scene(cornell_path)
    assert scene.warnings == []
    assert (scene.width, scene.height) == (512, 512)
    assert scene.num_triangles == 32
    assert scene.num_emitters == 2  # the light quad's two triangles
    tan_w, tan_h = scene.data.camera.tan_half_angles(512, 512)
    assert tan_w == pytest.approx(12.5 / 35.0) and tan_h == pytest.approx(12.5 / 35.0)


@pytest.mark.parametrize("text", ["#usda 1.0\ndef Mesh \"M\" {\n  point3f[] points = [(0,0,\n",
                                  "this is not usd at all\x00\x01",
                                  ""])
def test_malformed_files_raise_scene_error(tmp_path, text):
    path = tmp_path / "bad.usda"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value)


def test_missing_file_is_a_scene_error(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "nope.usda")


def test_out_of_range_indices_are_an_error_naming_the_prim(tmp_path):
    stage = new_stage(tmp_path / "i.usda")
    add_mesh(stage, "/World/Broken", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 7])
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match="/World/Broken"):
        load_scene(tmp_path / "i.usda")


def test_negative_face_vertex_counts_are_named_as_such(tmp_path):
    stage = new_stage(tmp_path / "c.usda")
    add_mesh(stage, "/World/Neg", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)], [3, 4, -3], [0, 1, 2, 1])
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match=r"/World/Neg: faceVertexCounts has 1 negative entries \(the first, -3, at face 2\)"):
        load_scene(tmp_path / "c.usda")


def test_an_authored_zero_aperture_is_an_error_not_the_fallback(tmp_path):
    stage = new_stage(tmp_path / "a.usda")
    add_mesh(stage, "/World/M", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    cam = add_camera(stage, "/Cam", translate=(0, 0, 5))
    cam.GetHorizontalApertureAttr().Set(0.0)
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match=r"/Cam: focalLength and apertures must be positive \(got 50.0, 0.0"):
        load_scene(tmp_path / "a.usda")


def test_nan_points_drop_their_triangles_with_a_warning(tmp_path):
    stage = new_stage(tmp_path / "n.usda")
    nan = float("nan")
    pts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (nan, 0, 0)]
    add_mesh(stage, "/M", pts, [3, 3], [0, 1, 2, 0, 1, 3])
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / "n.usda")
    assert scene.num_triangles == 1
    assert any("NaN" in w for w in scene.warnings)
    img = scene.render_tile(0, 0, 8, 8, spp=2)
    assert np.isfinite(img).all()


def test_concave_quads_are_split_inside_themselves(tmp_path):
    """A dart with its reflex vertex at corner 1: the fan's diagonal 0-2 would lie outside."""
    stage = new_stage(tmp_path / "dart.usda")
    dart = [(2, -1, 0), (0.5, 0, 0), (2, 1, 0), (0, 0, 0)]   # shoelace area 0.5
    add_mesh(stage, "/Dart", dart, [4], [0, 1, 2, 3])
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "dart.usda"))
    p = data.positions[data.indices]
    z = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
    assert (z > 0).all()  # both triangles keep the polygon's orientation
    assert triangle_areas(data).sum() == pytest.approx(0.5)
