"""Cameras as USD writes them: orthographic projection, aperture offsets (shifted image
windows) and the choice of camera (`camera=`, `tessera render --camera`). Expected
windows and pixel positions come from pxr's own GfCamera / GfFrustum, not from Tessera."""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom

from tessera import render
from tessera_renderer import SceneError, load_scene
from tessera_renderer.usd import translate_stage
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, emission_only, new_stage

W = H = 64


def _square_scene(path, *, camera_z=8.0, projection="perspective", offsets=(0.0, 0.0), cameras=("/Cam",)):
    """A unit emitting square x, y in [0, 1] at z = 0 on a black backdrop far behind, seen
    by cameras on the +z axis looking down -z."""
    stage = new_stage(path)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(1, 1, 1))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    add_mesh(stage, "/World/Square", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3], glow)
    add_mesh(stage, "/World/Back", [(-50, -50, -40), (50, -50, -40), (50, 50, -40), (-50, 50, -40)], [4],
             [0, 1, 2, 3], black)
    cams = []
    for k, cam_path in enumerate(cameras):
        cam = add_camera(stage, cam_path, (0.25 * k, 0.0, camera_z), focal=50.0, haperture=40.0, vaperture=40.0)
        cam.CreateProjectionAttr(projection)
        cam.CreateHorizontalApertureOffsetAttr(offsets[0])
        cam.CreateVerticalApertureOffsetAttr(offsets[1])
        cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 1000.0))
        cams.append(cam)
    add_render_settings(stage, cams[0], (W, H))
    emission_only(stage)
    stage.GetRootLayer().Save()
    return stage, cams


def _usd_pixel_box(cam: UsdGeom.Camera, corners) -> tuple[float, float, float, float]:
    """Where USD's own frustum (GfCamera -> GfFrustum matrices) puts world points, in
    raster coordinates of a W x H image (x right, y down): the bounds of the corners."""
    gf = cam.GetCamera(0)
    frustum = gf.frustum
    m = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    xs, ys = [], []
    for p in corners:
        ndc = m.Transform(Gf.Vec3d(*p))
        xs.append((ndc[0] + 1) / 2 * W)
        ys.append((1 - ndc[1]) / 2 * H)
    return min(xs), max(xs), min(ys), max(ys)


def _lit_box(rgba: np.ndarray) -> tuple[float, float, float, float]:
    """The emitter's extent in raster coordinates from the image: with a box filter, column
    x's mean is the fraction of it covered, so the edges are found to sub-pixel accuracy."""
    lum = rgba[..., 0]
    cols, rows = lum.max(axis=0), lum.max(axis=1)
    def edges(profile):
        lit = np.nonzero(profile > 0.0)[0]
        lo, hi = lit[0], lit[-1]
        return lo + 1 - profile[lo], hi + profile[hi]
    x0, x1 = edges(cols)
    y0, y1 = edges(rows)
    return x0, x1, y0, y1


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_window_is_usds_own_frustum_window(tmp_path, projection):
    stage, (cam,) = _square_scene(tmp_path / "s.usda", projection=projection, offsets=(6.0, -3.0))
    data = translate_stage(str(tmp_path / "s.usda"))
    half_w, half_h, cx, cy = data.camera.window(W, H)
    window = cam.GetCamera(0).frustum.GetWindow()  # GfRange2d: at distance 1 / in scene units
    assert (cx - half_w, cx + half_w) == pytest.approx((window.GetMin()[0], window.GetMax()[0]), rel=1e-9)
    assert (cy - half_h, cy + half_h) == pytest.approx((window.GetMin()[1], window.GetMax()[1]), rel=1e-9)
    assert data.camera.orthographic == (projection == "orthographic")
    assert not any("orthographic" in w or "offset" in w for w in data.warnings), data.warnings


@pytest.mark.parametrize("projection,offsets", [("orthographic", (0.0, 0.0)), ("orthographic", (5.0, -2.5)),
                                                ("perspective", (5.0, -2.5))])
def test_square_lands_where_usds_frustum_projects_it(tmp_path, projection, offsets):
    """The rendered square's edges against GfFrustum's projection of its corners, to 0.05
    pixel; the smallest error detected is shown by a control shifted by 0.25 pixel."""
    stage, (cam,) = _square_scene(tmp_path / "s.usda", projection=projection, offsets=offsets)
    image = render(tmp_path / "s.usda", spp=64, integrator="path", variance=False)
    got = np.array(_lit_box(image.rgb))
    expected = np.array(_usd_pixel_box(cam, [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]))
    assert np.abs(got - expected).max() < 0.05, (got, expected)
    assert np.abs(got + 0.25 - expected).max() >= 0.05  # the check sees a quarter pixel
    if offsets != (0.0, 0.0):  # the offset moved it: not the centred image's place
        _, (centred,) = _square_scene(tmp_path / "c.usda", projection=projection)
        assert np.abs(np.array(_usd_pixel_box(centred, [(0, 0, 0), (1, 1, 0)])) - expected).max() > 4


def test_orthographic_size_does_not_change_with_distance(tmp_path):
    """Parallel rays: the square covers the same pixels from 3 and from 30 units away (and a
    perspective camera's image shrinks tenfold), each matching GfFrustum."""
    boxes = {}
    for projection in ("orthographic", "perspective"):
        for z in (3.0, 30.0):
            path = tmp_path / f"{projection}{int(z)}.usda"
            _, (cam,) = _square_scene(path, camera_z=z, projection=projection)
            image = render(path, spp=16, integrator="path", variance=False)
            boxes[projection, z] = np.array(_lit_box(image.rgb))
            expected = _usd_pixel_box(cam, [(0, 0, 0), (1, 1, 0)])
            assert np.abs(boxes[projection, z] - expected).max() < 0.05
    widths = {k: b[1] - b[0] for k, b in boxes.items()}
    # Orthographic: 40 mm aperture = 4 scene units over 64 pixels, 16 pixels a unit.
    assert widths["orthographic", 3.0] == pytest.approx(16.0, abs=0.05)
    assert widths["orthographic", 30.0] == pytest.approx(16.0, abs=0.05)
    assert widths["perspective", 3.0] / widths["perspective", 30.0] == pytest.approx(10.0, rel=0.02)


def test_orthographic_image_agrees_between_path_and_bdpt(tmp_path):
    """The parallel camera's importance in bdpt (light-to-camera connections, per-film-area
    densities) against path tracing's camera rays on a lit diffuse floor: the image means
    agree to within 4 standard errors, which is 1 % here; a 2 % perturbation is detected."""
    stage = new_stage(tmp_path / "floor.usda")
    white = add_material(stage, "/Looks/White", diffuse=(0.8, 0.8, 0.8))
    add_mesh(stage, "/World/Floor", [(-3, 0, -3), (-3, 0, 3), (3, 0, 3), (3, 0, -3)], [4], [0, 1, 2, 3], white)
    add_mesh(stage, "/World/Wall", [(-3, 0, -1), (3, 0, -1), (3, 2, -1), (-3, 2, -1)], [4], [0, 1, 2, 3], white)
    light = stage.DefinePrim("/World/Key", "SphereLight")
    light.CreateAttribute("inputs:radius", Sdf.ValueTypeNames.Float).Set(0.2)
    light.CreateAttribute("inputs:intensity", Sdf.ValueTypeNames.Float).Set(30.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0.5, 1.5, 0.5))
    cam = add_camera(stage, "/Cam", (0, 0, 0), haperture=40.0, vaperture=40.0)
    cam.CreateProjectionAttr("orthographic")
    cam.CreateHorizontalApertureOffsetAttr(4.0)
    xf = UsdGeom.Xformable(cam)
    xf.ClearXformOpOrder()
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 3, 3))
    xf.AddRotateXOp().Set(-45.0)
    add_render_settings(stage, cam, (24, 24))
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / "floor.usda")
    means = {}
    for integrator in ("path", "bdpt"):
        runs = [render(scene, spp=128, seed=s, integrator=integrator, variance=False).rgb[..., 1].mean()
                for s in range(6)]
        means[integrator] = (np.mean(runs), np.std(runs, ddof=1) / np.sqrt(len(runs)))
    (mp, sp), (mb, sb) = means["path"], means["bdpt"]
    se = np.hypot(sp, sb)
    assert mp > 0.05
    assert 4 * se < 0.01 * mp, (means, "the comparison cannot resolve 1 %")
    assert abs(mb - mp) < 4 * se, means
    assert abs(1.02 * mb - mp) > 4 * se, means  # negative control: 2 % off is caught


def test_camera_is_chosen_by_path_over_the_render_settings(tmp_path):
    _square_scene(tmp_path / "two.usda", cameras=("/Cams/A", "/Cams/B"))
    default = translate_stage(str(tmp_path / "two.usda"))
    assert default.camera.source == "/Cams/A"  # the RenderSettings' camera
    chosen = translate_stage(str(tmp_path / "two.usda"), camera="/Cams/B")
    assert chosen.camera.source == "/Cams/B"
    assert chosen.world_offset == pytest.approx((0.25, 0.0, 8.0))
    a = render(tmp_path / "two.usda", spp=4, variance=False).rgb
    b = render(tmp_path / "two.usda", spp=4, variance=False, camera="/Cams/B").rgb
    # /Cams/B sits 0.25 units to the right; at the square's depth, 8, the 40 mm aperture
    # over 50 mm spans 6.4 units in 64 pixels, 10 pixels a unit: the square moves 2.5 left.
    xa, xb = _lit_box(a)[0], _lit_box(b)[0]
    assert xa - xb == pytest.approx(2.5, abs=0.05)
    for bad, message in [("/Cams/C", r"camera /Cams/C does not exist \(the stage's cameras: /Cams/A, /Cams/B\)"),
                         ("/World/Square", r"camera /World/Square is not a Camera prim"),
                         ("Cams/A", r"is not an absolute prim path")]:
        with pytest.raises(SceneError, match=message):
            load_scene(tmp_path / "two.usda", camera=bad)


def test_first_of_several_cameras_is_named_with_the_option_to_pick(tmp_path):
    stage, _ = _square_scene(tmp_path / "two.usda", cameras=("/Cams/A", "/Cams/B"))
    stage.RemovePrim("/Render")
    stage.SetMetadata("renderSettingsPrimPath", "")
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "two.usda"))
    assert "2 cameras and no RenderSettings camera; using /Cams/A (--camera picks another)" in data.warnings
    data = translate_stage(str(tmp_path / "two.usda"), camera="/Cams/B")
    assert not any("cameras and no RenderSettings camera" in w for w in data.warnings)


def test_orthographic_fstop_is_named_not_silently_dropped(tmp_path):
    stage, (cam,) = _square_scene(tmp_path / "o.usda", projection="orthographic")
    cam.CreateFStopAttr(2.8)
    cam.CreateFocusDistanceAttr(5.0)
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "o.usda"))
    assert data.camera.lens_radius == 0.0
    assert any("/Cam: fStop 2.8 on an orthographic camera" in w for w in data.warnings), data.warnings


def test_cli_camera_option_renders_through_that_camera_and_names_a_missing_one(tmp_path, capsys):
    import OpenImageIO as oiio

    from tessera_cli.cli import main

    _square_scene(tmp_path / "two.usda", cameras=("/Cams/A", "/Cams/B"))
    boxes = {}
    for cam in ("/Cams/A", "/Cams/B"):
        out = tmp_path / f"{cam[-1]}.exr"
        assert main(["render", str(tmp_path / "two.usda"), "--spp", "16", "-q", "--camera", cam, "-o", str(out)]) == 0
        boxes[cam] = _lit_box(oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[..., :3])
    assert boxes["/Cams/A"][0] - boxes["/Cams/B"][0] == pytest.approx(2.5, abs=0.05)  # as above
    assert main(["render", str(tmp_path / "two.usda"), "-q", "--camera", "/Cams/Z"]) == 2
    assert "camera /Cams/Z does not exist (the stage's cameras: /Cams/A, /Cams/B)" in capsys.readouterr().err

