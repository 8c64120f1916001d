"""Transform motion blur from USD: the camera's shutter:open/close around the render's time
code, xformOp time samples turned into moving instances and points time samples into
deforming prototypes (usd/motion.py).

The expected images do not come from the motion code: a sliding or stretching emitter's
ramp is a closed form, and a rotating or tilting prim must equal the mean of static renders at
uniformly spaced time codes, each of which pxr evaluates itself (shutter (0, 0))."""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdLux
from scipy import stats

from tessera import render
from tessera_renderer import SceneError, _core, load_scene
from tessera_renderer.scene_blob import scene_from_blob, translate_to_blob
from tessera_renderer.usd import translate_stage
from tessera_renderer.usd.lights import light_kind_number
from tessera_renderer.usd.motion import MAX_TIME_STEPS, MOTION_TOLERANCE
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, emission_only, new_stage

W = H = 16
LE = 2.0
X0, DISTANCE = -1.25, 1.5  # the quad's left edge at shutter open, and how far it slides


def _ortho_camera(stage, *, width=4.0, shutter=(-0.5, 0.5), translate=(0, 0, 0)):
    cam = add_camera(stage, "/Cam", translate, haperture=10 * width, vaperture=10 * width)
    cam.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    cam.CreateShutterOpenAttr(shutter[0])
    cam.CreateShutterCloseAttr(shutter[1])
    return cam


def _timed_stage(path):
    stage = new_stage(path)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    return stage


def _sliding_quad(path, *, keys=None, shutter=(-0.5, 0.5)):
    """A unit-wide emitting quad (x in [0, 1], y in [-1, 1], z = -3) under an Xform whose
    translate is keyed at frames 0.5 and 1.5 (the shutter around frame 1), over a black
    backdrop, seen by a 4-unit-wide orthographic camera looking down -z."""
    stage = _timed_stage(path)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(LE, LE, LE))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    mover = UsdGeom.Xform.Define(stage, "/Mover")
    op = mover.AddTranslateOp()
    for t, x in (keys or {0.5: X0, 1.5: X0 + DISTANCE}).items():
        op.Set(Gf.Vec3d(x, 0, 0), t)
    add_mesh(stage, "/Mover/Quad", [(0, -1, -3), (1, -1, -3), (1, 1, -3), (0, 1, -3)], [4], [0, 1, 2, 3], glow)
    add_mesh(stage, "/Back", [(-50, -50, -6), (50, -50, -6), (50, 50, -6), (-50, 50, -6)], [4], [0, 1, 2, 3], black)
    add_render_settings(stage, _ortho_camera(stage, shutter=shutter), (W, H))
    emission_only(stage)
    stage.GetRootLayer().Save()
    return path


def _ramp(x0: float, distance: float) -> np.ndarray:
    """Column means of the sliding quad: the fraction of the column-and-shutter box it
    covers (x0 + D t <= x <= x0 + D t + 1 for t in [0, 1]), times Le."""
    x = -2.0 + (np.arange(W)[:, None] + (np.arange(4000)[None, :] + 0.5) / 4000) / 4.0
    if distance == 0:
        return LE * ((x >= x0) & (x <= x0 + 1)).mean(axis=1)
    lo = np.clip((x - 1 - x0) / distance, 0, 1)
    hi = np.clip((x - x0) / distance, 0, 1)
    return LE * (hi - lo).mean(axis=1)


def _assert_columns(mean, se, K, expected, frozen, scale):
    """Each column's mean within its one-sample t limit (K - 1 degrees of freedom,
    Bonferroni over the columns at 1e-3) of the closed form `expected`; every limit within
    1 % of `scale`, so the negative controls -- the image scaled by 0.98, and the closed
    form of the scene frozen at mid-shutter -- must fail."""
    critical = stats.t.ppf(1 - 1e-3 / (2 * W), K - 1)
    assert (critical * se <= 0.01 * scale).all(), critical * se / scale
    fails = lambda values, wanted: np.abs(values - wanted) > np.maximum(critical * se, 1e-6)
    assert not fails(mean, expected).any(), (mean, expected)
    assert fails(0.98 * mean, expected).any(), "the 2 % negative control passed"
    assert fails(mean, frozen).any(), "the scene frozen at mid-shutter passed"


def _columns(scene, integrator, seeds, spp):
    runs = [render(scene, integrator=integrator, spp=spp, seed=s, variance=False).rgba[4:12, :, 0].mean(axis=0)
            for s in seeds]
    return np.mean(runs, axis=0), np.std(runs, axis=0, ddof=1) / np.sqrt(len(runs))


@pytest.mark.parametrize("integrator", ["path", "bdpt"])
def test_a_quad_keyed_to_slide_gives_the_closed_form_ramp(tmp_path, integrator):
    scene = load_scene(_sliding_quad(tmp_path / "slide.usda"))
    assert scene.has_motion and scene.data.shutter == (0.5, 1.5) and scene.data.time_code == 1.0
    ramp = _ramp(X0, DISTANCE)
    assert 0.1 * LE < ramp[4] < 0.9 * LE  # partly covered columns on both sides
    K = 24
    mean, se = _columns(scene, integrator, range(K), 256 if integrator == "path" else 128)
    _assert_columns(mean, se, K, ramp, _ramp(X0 + 0.5 * DISTANCE, 0), LE)


def test_shutter_override_and_frame_choose_the_interval(tmp_path):
    path = _sliding_quad(tmp_path / "slide.usda")
    still = load_scene(path, shutter=(0, 0))
    assert not still.has_motion and still.data.shutter is None
    img = render(still, spp=16, variance=False).rgba[8, :, 0]
    np.testing.assert_allclose(img, _ramp(X0 + 0.5 * DISTANCE, 0), atol=1e-6)  # the frame-1 quad, sharp
    # Half the shutter, opening at the frame: the quad slides from mid-way to the end.
    half = load_scene(path, shutter=(0, 0.5))
    assert half.data.shutter == (1.0, 1.5)
    mats = half.data.motion_transforms
    np.testing.assert_allclose(mats[[0, -1], 3, 0], [X0 + 0.5 * DISTANCE, X0 + DISTANCE], atol=1e-6)
    # frame= moves the interval: at frame 0 it ends on the first key, where USD holds the
    # quad still; at frame 0.5 it covers the first half of the slide.
    early = load_scene(path, frame=0, shutter=(-0.5, 0.5))
    assert not early.has_motion and early.data.shutter == (-0.5, 0.5)
    np.testing.assert_allclose(load_scene(path, frame=0.5).data.motion_transforms[[0, -1], 3, 0],
                               [X0, X0 + 0.5 * DISTANCE], atol=1e-6)
    with pytest.raises(SceneError, match="open <= close"):
        load_scene(path, shutter=(0.5, -0.5))


def test_time_steps_follow_the_keys_and_the_rotation(tmp_path):
    # Keys on the shutter's quarter points, with a stop: 5 steps land on every key.
    keyed = translate_stage(str(_sliding_quad(tmp_path / "keyed.usda",
                                               keys={0.5: 0.0, 0.75: 1.0, 1.0: 1.0, 1.25: 3.0, 1.5: 3.0})))
    assert list(keyed.motion_time_steps) == [5]
    np.testing.assert_allclose(keyed.motion_transforms[:, 3, 0], [0.0, 1.0, 1.0, 3.0, 3.0], atol=1e-6)
    # A rotation: more steps than its two keys, until the chords follow USD's own arc.
    path = _rotating_scene(tmp_path / "spin.usda")
    data = translate_stage(str(path), camera_relative=False)
    assert len(data.motion_time_steps) == 2  # the bar and the plate
    steps = int(data.motion_time_steps[0])  # the bar, met first
    assert 2 < steps <= MAX_TIME_STEPS
    stage = Usd.Stage.Open(str(path))
    bar = stage.GetPrimAtPath("/Spin/Bar")
    mats = data.motion_transforms[:steps].astype(np.float64)
    corners = np.array([[x, 0.0, z, 1.0] for x in (-1.5, 1.5) for z in (-0.25, 0.25)])
    # motion_steps' bound: the chord error at most MOTION_TOLERANCE of the largest world
    # coordinate of the bar's corners.
    bound = MOTION_TOLERANCE * np.abs(np.einsum("cj,sjk->sck", corners, mats)[..., :3]).max()
    for u in np.linspace(0, 1, 37):
        usd = np.array(UsdGeom.XformCache(Usd.TimeCode(0.5 + u)).GetLocalToWorldTransform(bar))
        k = min(int(u * (steps - 1)), steps - 2)
        f = u * (steps - 1) - k
        lerp = (1 - f) * mats[k] + f * mats[k + 1]
        assert np.abs(corners @ (lerp - usd)).max() <= 1.01 * bound + 1e-6, u


def _rotating_scene(path, *, frozen_at=None):
    """Seen from above (orthographic, looking down -y): an emitting bar spinning 90 degrees
    about y and a diffuse plate tilting 0 -> 60 degrees about x under a distant light from
    straight above (its radiance follows cos(tilt): the normals must turn with it), keyed
    at frames 0.5 and 1.5, the shutter around frame 1."""
    stage = _timed_stage(path)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(1.5, 1.5, 1.5))
    grey = add_material(stage, "/Looks/Grey", diffuse=(0.8, 0.8, 0.8))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    spin = UsdGeom.Xform.Define(stage, "/Spin")
    spin.AddTranslateOp().Set(Gf.Vec3d(-1.6, 0, 0))
    rot = spin.AddRotateYOp()
    rot.Set(0.0, 0.5)
    rot.Set(90.0, 1.5)
    add_mesh(stage, "/Spin/Bar", [(-1.5, 0, 0.25), (1.5, 0, 0.25), (1.5, 0, -0.25), (-1.5, 0, -0.25)], [4],
             [0, 1, 2, 3], glow)
    tilt = UsdGeom.Xform.Define(stage, "/Tilt")
    tilt.AddTranslateOp().Set(Gf.Vec3d(1.6, 0.5, 0))
    op = tilt.AddRotateXOp()
    op.Set(0.0, 0.5)
    op.Set(60.0, 1.5)
    add_mesh(stage, "/Tilt/Plate", [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)], [4], [0, 1, 2, 3], grey)
    return _sunlit_from_above(stage, black, path)


def _sunlit_from_above(stage, black, path):
    """A black floor below, a sun from straight above (illuminance 3), and an orthographic
    camera looking down -y over 7 x 3.5 units (32 x 16) with the shutter around frame 1."""
    add_mesh(stage, "/Floor", [(-50, -5, 50), (50, -5, 50), (50, -5, -50), (-50, -5, -50)], [4], [0, 1, 2, 3], black)
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.AddRotateXOp().Set(-90.0)  # emits along -y
    sun.CreateIntensityAttr(3.0)
    sun.CreateAngleAttr(0.0)
    cam = add_camera(stage, "/Cam", (0, 10, 0), haperture=70, vaperture=35)
    UsdGeom.Xformable(cam).AddRotateXOp().Set(-90.0)
    cam.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    cam.CreateShutterOpenAttr(-0.5)
    cam.CreateShutterCloseAttr(0.5)
    add_render_settings(stage, cam, (32, 16))
    stage.GetRootLayer().Save()
    return path


def _blocks(rgba: np.ndarray) -> np.ndarray:
    """Means of 4 x 4-pixel blocks of the red channel (8 x 4 blocks)."""
    return rgba[..., 0].reshape(4, 4, 8, 4).mean(axis=(1, 3)).ravel()


def _assert_mean_of_static_renders(path, integrator, M=24, K=12, spp=64):
    """The motion-blurred render of `path` against the mean of M static renders at the
    instants (m + 1/2) / M of the shutter around frame 1 (shutter (0, 0): pxr evaluates
    each), per 4 x 4 block, by Welch's t test (Bonferroni over the blocks at 1e-3). Every
    limit is within 1 % of the brightest block, so a 2 % error is found: the 2 % negative
    control and the scene frozen at mid-shutter must both fail."""
    moving = load_scene(path)
    assert moving.has_motion
    instants = [load_scene(path, frame=0.5 + (m + 0.5) / M, shutter=(0, 0)) for m in range(M)]
    assert not any(s.has_motion for s in instants)
    ref = np.array([np.mean([_blocks(render(s, integrator="path", spp=spp, seed=1000 * k + m, variance=False).rgba)
                             for m, s in enumerate(instants)], axis=0) for k in range(K)])
    blur = np.array([_blocks(render(moving, integrator=integrator, spp=M * spp // (1 if integrator == "path" else 2),
                                    seed=k, variance=False).rgba) for k in range(K)])
    peak = ref.mean(axis=0).max()
    assert peak > 0.3

    def failing(values):
        t, _ = stats.ttest_ind(values, ref, axis=0, equal_var=False)
        se = np.sqrt(values.var(axis=0, ddof=1) / K + ref.var(axis=0, ddof=1) / K)
        df = se ** 4 / ((values.var(axis=0, ddof=1) / K) ** 2 / (K - 1) + (ref.var(axis=0, ddof=1) / K) ** 2 / (K - 1)
                        + 1e-300)
        critical = stats.t.ppf(1 - 1e-3 / (2 * len(se)), np.maximum(df, 1))
        # Blocks lying wholly on one facet under a delta light have no noise at all: there
        # only float rounding (1e-4 of the peak) may differ.
        limit = np.maximum(critical * se, 1e-4 * peak)
        return limit, np.abs(values.mean(axis=0) - ref.mean(axis=0)) > limit

    limit, fail = failing(blur)
    assert (limit <= 0.01 * peak).all(), np.round(limit / peak, 4)
    assert not fail.any(), (blur.mean(axis=0) - ref.mean(axis=0))[fail]
    assert failing(blur + 0.02 * peak)[1].any(), "the 2 % negative control passed"
    mid = load_scene(path, frame=1.0, shutter=(0, 0))
    frozen = np.array([_blocks(render(mid, spp=M * spp, seed=k, variance=False).rgba) for k in range(K)])
    assert failing(frozen)[1].any(), "the frozen mid-shutter frame passed: the test cannot see motion"


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["path", "bdpt"])
def test_rotating_and_tilting_prims_equal_the_mean_of_static_renders(tmp_path, integrator):
    _assert_mean_of_static_renders(_rotating_scene(tmp_path / "spin.usda"), integrator)


def _tent_scene(path):
    """Seen from above (orthographic, looking down -y) under a distant light from straight
    above: a 3 x 3 tent of four diffuse facets whose apex (its `points`, keyed at frames 0.5
    and 1.5) rises from the plane to 1.5 above it, so each facet tilts from 0 to 45 degrees
    and its shading (cos of the tilt) changes: a deforming mesh."""
    stage = _timed_stage(path)
    grey = add_material(stage, "/Looks/Grey", diffuse=(0.8, 0.8, 0.8))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    corners = [(-1.5, 0, -1.5), (1.5, 0, -1.5), (1.5, 0, 1.5), (-1.5, 0, 1.5)]
    # Triangles (corner k, apex, corner k + 1) face +y for every apex height.
    tris = [i for k in range(4) for i in (k, 4, (k + 1) % 4)]
    tent = add_mesh(stage, "/Tent", corners + [(0, 0, 0)], [3] * 4, tris, grey)
    for t, h in ((0.5, 0.0), (1.5, 1.5)):
        tent.GetPointsAttr().Set([Gf.Vec3f(*c) for c in corners] + [Gf.Vec3f(0, h, 0)], t)
    return _sunlit_from_above(stage, black, path)


@pytest.mark.slow
def test_a_deforming_mesh_equals_the_mean_of_static_renders(tmp_path):
    _assert_mean_of_static_renders(_tent_scene(tmp_path / "tent.usda"), "path")


def test_a_moving_scene_travels_in_its_blob_and_renders_the_same(tmp_path):
    path = _sliding_quad(tmp_path / "slide.usda")
    local = render(load_scene(path), spp=32, seed=3, variance=False).rgba
    blob = translate_to_blob(path)
    from_blob = scene_from_blob(blob)
    assert from_blob.has_motion and from_blob.data.shutter == (0.5, 1.5)
    np.testing.assert_array_equal(render(from_blob, spp=32, seed=3, variance=False).rgba, local)
    still = scene_from_blob(translate_to_blob(path, shutter=(0, 0)))
    assert not still.has_motion


def test_moving_light_kind_numbers_come_from_the_core():
    """usd/lights.py reads the kind numbers from the core's list (lights/light_kinds.h), not
    a copy: the numbers blobs have always carried, and a kind that cannot move is refused."""
    assert [name for name, *_ in _core.light_kinds()][:5] == ["triangle", "sphere", "point", "distant", "dome"]
    assert [light_kind_number(k) for k in ("sphere", "point", "distant", "dome")] == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="triangle"):
        light_kind_number("triangle")  # triangles move with their mesh, not as lights


def test_moving_lights_follow_usd_relative_to_the_camera(tmp_path):
    """A SphereLight keyed to move (and the camera, so the data is camera-relative) gets its
    rigid motion: at every step its centre moved by the step's transform is where USD puts
    it, less the camera offset; a turning DistantLight's direction turns as USD's does."""
    path = _sliding_quad(tmp_path / "slide.usda")
    stage = Usd.Stage.Open(str(path))
    stage.RemovePrim("/EmissionOnly")  # its own lights below are the ones checked
    cam = UsdGeom.Xformable(stage.GetPrimAtPath("/Cam"))
    cam.GetOrderedXformOps()[0].Set(Gf.Vec3d(0.1, 0, 0), 0.5)
    cam.GetOrderedXformOps()[0].Set(Gf.Vec3d(0.3, 0, 0), 1.5)
    ball = UsdLux.SphereLight.Define(stage, "/Ball")
    ball.AddTranslateOp().Set(Gf.Vec3d(0, 0, -2), 0.5)
    ball.GetOrderedXformOps()[0].Set(Gf.Vec3d(0, 1, -2), 1.5)
    ball.CreateRadiusAttr(0.1)
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    turn = sun.AddRotateYOp()
    turn.Set(0.0, 0.5)
    turn.Set(90.0, 1.5)
    stage.GetRootLayer().Save()
    data = translate_stage(str(path))
    assert not any("blurred" in w for w in data.warnings), data.warnings
    assert list(data.light_motion_kinds) == [1, 3]  # the sphere, then the distant light
    steps = data.light_motion_time_steps
    assert steps[0] == 2 and steps[1] > 2  # a slide; a quarter turn needs more
    offset = np.array(data.world_offset)
    centre = np.append(data.sphere_lights[0, :3], 1.0)
    deltas = data.light_motion_transforms[:steps[0]].astype(np.float64)
    for k, t in enumerate(np.linspace(0.5, 1.5, steps[0])):
        usd = np.array(UsdGeom.XformCache(Usd.TimeCode(t)).GetLocalToWorldTransform(stage.GetPrimAtPath("/Ball")))
        np.testing.assert_allclose((centre @ deltas[k])[:3], usd[3, :3] - offset, atol=1e-5)
    turning = data.light_motion_transforms[steps[0]:].astype(np.float64)
    for k, t in enumerate(np.linspace(0.5, 1.5, steps[1])):
        usd = np.array(UsdGeom.XformCache(Usd.TimeCode(t)).GetLocalToWorldTransform(stage.GetPrimAtPath("/Sun")))
        np.testing.assert_allclose(data.distant_lights[0, :3] @ turning[k, :3, :3], -usd[2, :3], atol=1e-5)
    # The blob carries it; without a shutter nothing moves.
    assert scene_from_blob(translate_to_blob(path)).has_motion
    still = translate_stage(str(path), shutter=(0, 0))
    assert len(still.light_motion_kinds) == 0


def _lit_plate(path, light: str):
    """A Lambertian plate (displayColor 0.5, 4.5 units wide) at z = -3 seen by a pinhole
    whose view there is 4 x 4 units, lit by one light that moves over the shutter around
    frame 1: a point (SphereLight treatAsPoint, r = 0.25) or a sphere light of intensity
    L pi r^2 = 6 W/sr sliding from x = -3 to 3 at height 3.5 (behind the pinhole), or a
    DistantLight of illuminance 2 turning from straight on to 60 degrees about y."""
    stage = _timed_stage(path)
    plate = add_mesh(stage, "/Plate", [(-2.25, -2.25, -3), (2.25, -2.25, -3), (2.25, 2.25, -3), (-2.25, 2.25, -3)],
                     [4], [0, 1, 2, 3])
    plate.CreateDisplayColorAttr([(0.5, 0.5, 0.5)])
    if light == "distant":
        sun = UsdLux.DistantLight.Define(stage, "/Light")
        sun.CreateIntensityAttr(2.0)
        sun.CreateAngleAttr(0.0)
        op = sun.AddRotateYOp()
        op.Set(0.0, 0.5)
        op.Set(60.0, 1.5)
    else:
        lamp = UsdLux.SphereLight.Define(stage, "/Light")
        lamp.CreateRadiusAttr(0.25)
        lamp.CreateIntensityAttr(6.0 / (np.pi * 0.25 ** 2))
        lamp.CreateTreatAsPointAttr(light == "point")
        op = lamp.AddTranslateOp()
        op.Set(Gf.Vec3d(-3, 0, 0.5), 0.5)
        op.Set(Gf.Vec3d(3, 0, 0.5), 1.5)
    cam = add_camera(stage, "/Cam", (0, 0, 0), focal=30.0, haperture=40.0, vaperture=40.0)
    cam.CreateShutterOpenAttr(-0.5)
    cam.CreateShutterCloseAttr(0.5)
    add_render_settings(stage, cam, (W, H))
    stage.GetRootLayer().Save()
    return path


def _lit_columns(light: str, frozen: bool) -> np.ndarray:
    """The plate's column means (rows 4-12: y in [-1, 1]) of 0.5 / pi E averaged over the
    shutter: E = I h / d^3 for the sliding lights (I = 6, h = 3.5), E0 cos(phi) for the
    turning one (E0 = 2, phi from 0 to 60 degrees). Midpoint rule in x, y and t."""
    if light == "distant":
        mean_cos = 1.0 if frozen else np.sin(np.pi / 3) / (np.pi / 3)
        return np.full(W, 0.5 / np.pi * 2.0 * (np.cos(np.pi / 6) if frozen else mean_cos))
    n = 40
    x = -2.0 + (np.arange(W)[:, None, None, None] + (np.arange(n)[None, :, None, None] + 0.5) / n) / 4.0
    y = -1.0 + 2.0 * (np.arange(n)[None, None, :, None] + 0.5) / n
    xl = np.zeros((1, 1, 1, 1)) if frozen else -3.0 + 6.0 * (np.arange(n)[None, None, None, :] + 0.5) / n
    d2 = (x - xl) ** 2 + y ** 2 + 3.5 ** 2
    return 0.5 / np.pi * (6.0 * 3.5 / d2 ** 1.5).mean(axis=(1, 2, 3))


@pytest.mark.parametrize("light", ["point", "sphere", "distant"])
def test_moving_lights_give_the_closed_form_irradiance(tmp_path, light):
    scene = load_scene(_lit_plate(tmp_path / f"{light}.usda", light))
    assert scene.has_motion and len(scene.data.light_motion_kinds) == 1
    expected, frozen = _lit_columns(light, False), _lit_columns(light, True)
    K = 16
    mean, se = _columns(scene, "path", range(K), 256)
    _assert_columns(mean, se, K, expected, frozen, expected.max())


def test_a_stage_without_a_time_range_renders_its_default_time(tmp_path):
    stage = new_stage(tmp_path / "plain.usda")
    glow = add_material(stage, "/Glow", emissive=(1, 1, 1))
    add_mesh(stage, "/Q", [(0, 0, -2), (1, 0, -2), (1, 1, -2)], [3], [0, 1, 2], glow)
    add_render_settings(stage, _ortho_camera(stage), (W, H))
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "plain.usda"))
    assert data.time_code is None and data.shutter is None and len(data.motion_instances) == 0


def test_render_frames_writes_one_numbered_image_per_frame(tmp_path):
    """`tessera render --frames`: frames 0 and 2 hold the quad still at its first and last
    key (a sharp edge, the closed form); frame 1 is the blurred ramp."""
    import subprocess
    import sys

    from tessera_base.images import read_exr

    path = _sliding_quad(tmp_path / "slide.usda", keys={0.5: X0, 1.5: X0 + DISTANCE})
    r = subprocess.run([sys.executable, "-m", "tessera", "render", str(path), "-o", str(tmp_path / "shot.##.exr"),
                        "--frames", "0-2x2,1", "--spp", "256", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.glob("shot.*.exr")) == ["shot.00.exr", "shot.01.exr", "shot.02.exr"]
    assert r.stderr.index("frame 0 (1 of 3)") < r.stderr.index("frame 2 (2 of 3)") < r.stderr.index("frame 1 (3 of 3)")
    row = lambda n: read_exr(tmp_path / f"shot.{n:02d}.exr")[4:12, :, 0].mean(axis=0)
    np.testing.assert_allclose(row(0), _ramp(X0, 0), atol=1e-6)
    np.testing.assert_allclose(row(2), _ramp(X0 + DISTANCE, 0), atol=1e-6)
    assert np.abs(row(1) - _ramp(X0, DISTANCE)).max() < 0.05 * LE  # blurred (256 spp, one run)
    assert np.abs(row(1) - _ramp(X0 + 0.5 * DISTANCE, 0)).max() > 0.3 * LE
    bad = subprocess.run([sys.executable, "-m", "tessera", "render", str(path), "--frames", "3-1"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--frames: '3-1' must run upwards" in bad.stderr


@pytest.mark.parametrize("codes_per_second", [24.0, 48.0])
def test_point_instancer_velocities_give_the_closed_form_ramp(tmp_path, codes_per_second):
    """Two emitting quads of a PointInstancer: one with a velocity that slides it by
    DISTANCE over the shutter (velocities are per second: the stage's timeCodesPerSecond
    time codes, 24 unless authored), one still; each row of quads is a closed form."""
    stage = _timed_stage(tmp_path / "instancer.usda")
    stage.SetTimeCodesPerSecond(codes_per_second)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(LE, LE, LE))
    pi = UsdGeom.PointInstancer.Define(stage, "/Points")
    quad = add_mesh(stage, "/Points/Protos/Quad", [(0, 0, -3), (1, 0, -3), (1, 0.75, -3), (0, 0.75, -3)], [4],
                    [0, 1, 2, 3], glow)
    pi.CreatePrototypesRel().SetTargets([quad.GetPath()])
    pi.CreateProtoIndicesAttr([0, 0])
    mid = X0 + 0.5 * DISTANCE
    pi.CreatePositionsAttr().Set([Gf.Vec3f(mid, 0.25, 0), Gf.Vec3f(mid, -1.0, 0)], 1.0)
    pi.CreateVelocitiesAttr().Set([Gf.Vec3f(codes_per_second * DISTANCE, 0, 0), Gf.Vec3f(0, 0, 0)], 1.0)
    add_render_settings(stage, _ortho_camera(stage), (W, H))
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / "instancer.usda")
    # Three steps: one lands on the positions sample at the frame, inside the shutter.
    assert scene.has_motion and list(scene.data.motion_time_steps) == [3, 3]
    K = 24
    runs = [render(scene, spp=1024, seed=s, variance=False).rgba[..., 0] for s in range(K)]
    top = np.array([r[5:7].mean(axis=0) for r in runs])      # rows 5-6: y in [0.25, 0.75], the moving quad
    bottom = np.array([r[10:12].mean(axis=0) for r in runs])  # rows 10-11: y in [-1, -0.5], the still one
    critical = stats.t.ppf(1 - 1e-3 / (4 * W), K - 1)
    se = top.std(axis=0, ddof=1) / np.sqrt(K)
    assert (critical * se <= 0.01 * LE).all()
    fails = lambda values, expected: np.abs(values - expected) > np.maximum(critical * se, 1e-6)
    assert not fails(top.mean(axis=0), _ramp(X0, DISTANCE)).any(), top.mean(axis=0)
    assert fails(0.98 * top.mean(axis=0), _ramp(X0, DISTANCE)).any(), "the 2 % negative control passed"
    np.testing.assert_allclose(bottom.mean(axis=0), _ramp(mid, 0), atol=1e-6)  # the still quad, sharp


def _quad_with_velocities(path, codes_per_second: float, *, accelerate: bool = False, sampled: bool = True):
    """An emitting unit quad (y in [-1, 1], z = -3) whose points are sampled once, at the
    frame, centred on X0 + DISTANCE / 2, with `velocities` that slide it by DISTANCE over
    the shutter (per second: timeCodesPerSecond codes); `accelerate` adds an acceleration
    that moves it a further quarter unit (a t^2 / 2 over the half-shutter after the frame)."""
    stage = _timed_stage(path)
    stage.SetTimeCodesPerSecond(codes_per_second)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(LE, LE, LE))
    mid = X0 + 0.5 * DISTANCE
    points = [(mid, -1, -3), (mid + 1, -1, -3), (mid + 1, 1, -3), (mid, 1, -3)]
    quad = add_mesh(stage, "/Quad", points, [4], [0, 1, 2, 3], glow)
    speed = codes_per_second * DISTANCE  # units per second: DISTANCE per time code
    if sampled:
        quad.GetPointsAttr().Set(points, 1.0)
        quad.CreateVelocitiesAttr().Set([Gf.Vec3f(speed, 0, 0)] * 4, 1.0)
    else:
        quad.CreateVelocitiesAttr([Gf.Vec3f(speed, 0, 0)] * 4)
    if accelerate:
        quad.CreateAccelerationsAttr().Set([Gf.Vec3f(2.0 * codes_per_second ** 2, 0, 0)] * 4, 1.0)
    add_render_settings(stage, _ortho_camera(stage), (W, H))
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("codes_per_second", [24.0, 48.0])
def test_mesh_velocities_give_the_closed_form_ramp(tmp_path, codes_per_second):
    """A mesh whose points are sampled at the frame and whose `velocities` slide it by
    DISTANCE over the shutter deforms like a keyed one: the closed-form ramp per column
    (the 2 % control and the quad frozen at the frame fail). Accelerations add USD's
    a t^2 / 2; velocities on points without samples are named and left alone, as USD does."""
    path = _quad_with_velocities(tmp_path / "velocities.usda", codes_per_second)
    data = translate_stage(str(path), camera_relative=False)
    (proto,) = [p for p in data.prototypes if p.get("motion_positions") is not None]
    steps = np.concatenate([proto["positions"][None], proto["motion_positions"]])
    np.testing.assert_allclose(steps[[0, -1], 0, 0], [X0, X0 + DISTANCE], atol=1e-5)  # linear: 2 steps
    assert len(steps) == 2
    scene = load_scene(path)
    assert scene.has_motion
    K = 24
    mean, se = _columns(scene, "path", range(K), 256)
    _assert_columns(mean, se, K, _ramp(X0, DISTANCE), _ramp(X0 + 0.5 * DISTANCE, 0), LE)

    # x(t) = x_frame + v dt + a dt^2 / 2, dt in seconds from the frame: more steps, on the parabola.
    accelerated = translate_stage(str(_quad_with_velocities(tmp_path / "a.usda", codes_per_second, accelerate=True)),
                                  camera_relative=False)
    (proto,) = [p for p in accelerated.prototypes if p.get("motion_positions") is not None]
    xs = np.concatenate([proto["positions"][None], proto["motion_positions"]])[:, 0, 0]
    dt = np.linspace(-0.5, 0.5, len(xs))  # time codes from the frame
    parabola = X0 + 0.5 * DISTANCE + DISTANCE * dt + 0.5 * 2.0 * dt ** 2
    assert len(xs) > 2
    np.testing.assert_allclose(xs, parabola, atol=1e-4)

    # A simulation cache: the point count changes from sample to sample, and the frame's
    # sample with its velocities gives every step.
    stage = Usd.Stage.Open(str(path))
    quad = UsdGeom.Mesh(stage.GetPrimAtPath("/Quad"))
    quad.GetPointsAttr().Set([(0, 0, -3), (1, 0, -3), (1, 1, -3)], 0.0)
    quad.GetVelocitiesAttr().Set([Gf.Vec3f(0, 0, 0)] * 3, 0.0)
    stage.GetRootLayer().Save()
    (proto,) = [p for p in translate_stage(str(path), camera_relative=False).prototypes
                if p.get("motion_positions") is not None]
    np.testing.assert_allclose(proto["motion_positions"][-1][:, 0], [X0 + DISTANCE, X0 + DISTANCE + 1, X0 + DISTANCE + 1, X0 + DISTANCE],
                               atol=1e-5)

    unsampled = translate_stage(str(_quad_with_velocities(tmp_path / "u.usda", codes_per_second, sampled=False)))
    assert not any(p.get("motion_positions") is not None for p in unsampled.prototypes)
    assert sum("velocities on points without time samples" in w for w in unsampled.warnings) == 1


def test_a_camera_keyed_to_slide_past_a_still_quad_gives_the_same_ramp(tmp_path):
    """The quad stands still at x in [0, 1], seen from a camera keyed to slide from -X0 to
    -X0 - DISTANCE over the shutter: relative to the camera, the quad slides from X0 to
    X0 + DISTANCE, the closed-form ramp (light tracing connects to the camera where it is
    at each sample's instant)."""
    path = _sliding_quad(tmp_path / "still.usda", keys={0.5: 0.0, 1.5: 0.0})
    stage = Usd.Stage.Open(str(path))
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/Cam")).GetOrderedXformOps()[0]
    op.Set(Gf.Vec3d(-X0, 0, 0), 0.5)
    op.Set(Gf.Vec3d(-X0 - DISTANCE, 0, 0), 1.5)
    stage.GetRootLayer().Save()
    scene = load_scene(path)
    assert not scene.has_motion  # the quad's keys are equal: only the camera moves
    poses = np.array(scene.data.camera.motion).reshape(-1, 12)
    assert len(poses) == 2 and not any("camera motion" in w for w in scene.warnings)
    # Camera-relative coordinates: the camera sits at the origin at the frame (mid-shutter).
    np.testing.assert_allclose(poses[:, 0], [0.5 * DISTANCE, -0.5 * DISTANCE], atol=1e-9)
    assert scene_from_blob(translate_to_blob(path)).data.camera.motion == scene.data.camera.motion  # the farm's way
    ramp = _ramp(X0, DISTANCE)
    K = 24
    for integrator, spp in (("path", 256), ("light", 256)):
        mean, se = _columns(scene, integrator, range(K), spp)
        critical = stats.t.ppf(1 - 1e-3 / (4 * W), K - 1)
        assert (critical * se <= 0.01 * LE).all(), (integrator, critical * se)
        fails = lambda values: np.abs(values - ramp) > np.maximum(critical * se, 1e-6)
        assert not fails(mean).any(), (integrator, mean, ramp)
        assert fails(0.98 * mean).any(), "the 2 % negative control passed"
    # Still, at the frame, the camera is where USD puts it: the quad's edges are sharp.
    still = render(load_scene(path, shutter=(0, 0)), spp=16, variance=False).rgba[8, :, 0]
    np.testing.assert_allclose(still, _ramp(X0 + 0.5 * DISTANCE, 0), atol=1e-6)


def _edges_ramp(l0: float, l1: float, r0: float, r1: float) -> np.ndarray:
    """Column means of an emitter whose left edge runs from l0 to l1 and right edge from r0
    to r1 over the shutter: Le times the fraction of the column-and-shutter box with
    left(t) <= x <= right(t) (midpoint rule, 1000 x 1000 points per column)."""
    n = 1000
    x = -2.0 + (np.arange(W)[:, None, None] + (np.arange(n)[None, :, None] + 0.5) / n) / 4.0
    t = (np.arange(n)[None, None, :] + 0.5) / n
    return LE * ((x >= l0 + (l1 - l0) * t) & (x <= r0 + (r1 - r0) * t)).mean(axis=(1, 2))


def _stretching_quad(path, *, slide: float = 0.0, mid_key=None):
    """An emitting quad (y in [-1, 1], z = -3) whose points are keyed at frames 0.5 and 1.5
    (the shutter around frame 1): its left edge stays at x = -1, its right edge runs from
    -0.5 to 1, so it stretches from 0.5 to 2 units wide. Under an Xform keyed to slide it
    by `slide`; `mid_key` adds a points key at frame 1 with the right edge there."""
    stage = _timed_stage(path)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(LE, LE, LE))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    mover = UsdGeom.Xform.Define(stage, "/Mover")
    op = mover.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 0.5)
    op.Set(Gf.Vec3d(slide, 0, 0), 1.5)
    quad = add_mesh(stage, "/Mover/Quad", [(-1, -1, -3), (-0.5, -1, -3), (-0.5, 1, -3), (-1, 1, -3)], [4],
                    [0, 1, 2, 3], glow)
    keys = {0.5: -0.5, 1.5: 1.0, **({1.0: mid_key} if mid_key is not None else {})}
    for t, r in keys.items():
        quad.GetPointsAttr().Set([(-1, -1, -3), (r, -1, -3), (r, 1, -3), (-1, 1, -3)], t)
    add_mesh(stage, "/Back", [(-50, -50, -6), (50, -50, -6), (50, 50, -6), (-50, 50, -6)], [4], [0, 1, 2, 3], black)
    add_render_settings(stage, _ortho_camera(stage), (W, H))
    emission_only(stage)
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("integrator, slide", [("path", 0.0), ("bdpt", 0.0), ("path", 0.5)])
def test_a_mesh_keyed_to_stretch_gives_the_closed_form_coverage(tmp_path, integrator, slide):
    """A deforming mesh (points time-sampled), standing still or carried by a moving Xform:
    each column is Le times the fraction of the shutter its quad covers it."""
    scene = load_scene(_stretching_quad(tmp_path / "stretch.usda", slide=slide))
    assert scene.has_motion
    assert len(scene.data.motion_instances) == (1 if slide else 0)  # deforming in place: a still instance
    expected = _edges_ramp(-1.0, -1.0 + slide, -0.5, 1.0 + slide)
    frozen = _edges_ramp(-1.0 + slide / 2, -1.0 + slide / 2, 0.25 + slide / 2, 0.25 + slide / 2)
    K = 24
    mean, se = _columns(scene, integrator, range(K), 256 if integrator == "path" else 128)
    _assert_columns(mean, se, K, expected, frozen, LE)


def test_deformation_steps_land_on_the_points_keys_and_travel_in_the_blob(tmp_path):
    # A key at the frame, off the straight line between the other two: 3 steps hold all three.
    path = _stretching_quad(tmp_path / "keyed.usda", mid_key=0.75)
    data = translate_stage(str(path), camera_relative=False)
    (proto,) = [p for p in data.prototypes if p.get("motion_positions") is not None]
    steps = np.concatenate([proto["positions"][None], proto["motion_positions"]])
    assert steps.shape == (3, 4, 3)
    np.testing.assert_allclose(steps[:, 1, 0], [-0.5, 0.75, 1.0], atol=1e-6)
    np.testing.assert_allclose(steps[:, 0, 0], [-1.0, -1.0, -1.0], atol=1e-6)
    # Without a shutter the mesh is the frame's shape, flattened like any still prim.
    still = translate_stage(str(path), shutter=(0, 0), camera_relative=False)
    assert not any(p.get("motion_positions") is not None for p in still.prototypes)
    assert np.isclose(still.positions[:4, 0].max(), 0.75)  # the quad, then the backdrop
    # The blob carries the steps: the farm renders what a local render does.
    local = render(load_scene(path), spp=32, seed=3, variance=False).rgba
    from_blob = scene_from_blob(translate_to_blob(path))
    assert from_blob.has_motion
    np.testing.assert_array_equal(render(from_blob, spp=32, seed=3, variance=False).rgba, local)


def test_a_deforming_subdivision_surface_refines_each_step_and_gives_the_closed_form_coverage(tmp_path):
    """The stretching quad as a Catmull-Clark cage (one face, boundary edges and corners
    sharp: its limit surface is the quad itself), refined at the default level: each time
    step's cage is refined on its own, so the refined vertices follow the edges (checked
    against the cage's keys) and each column is the closed-form coverage."""
    path = _stretching_quad(tmp_path / "stretch.usda")
    stage = Usd.Stage.Open(str(path))
    UsdGeom.Mesh(stage.GetPrimAtPath("/Mover/Quad")).GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.catmullClark)
    stage.GetRootLayer().Save()
    data = translate_stage(str(path), camera_relative=False)
    assert not any("not motion-blurred" in w for w in data.warnings), data.warnings
    (proto,) = [p for p in data.prototypes if p.get("motion_positions") is not None]
    steps = np.concatenate([proto["positions"][None], proto["motion_positions"]])
    assert steps.shape[1] > 4  # refined vertices, not the cage's four
    np.testing.assert_allclose(steps[:, :, 0].min(axis=1), [-1.0, -1.0], atol=1e-5)
    np.testing.assert_allclose(steps[:, :, 0].max(axis=1), [-0.5, 1.0], atol=1e-5)
    scene = load_scene(path)
    K = 24
    mean, se = _columns(scene, "path", range(K), 256)
    _assert_columns(mean, se, K, _edges_ramp(-1.0, -1.0, -0.5, 1.0), _edges_ramp(-1.0, -1.0, 0.25, 0.25), LE)


def test_deforming_meshes_that_cannot_be_blurred_are_named_once(tmp_path):
    path = _stretching_quad(tmp_path / "stretch.usda")
    stage = Usd.Stage.Open(str(path))
    grow = UsdGeom.Mesh.Define(stage, "/Grow")
    grow.CreateFaceVertexCountsAttr([3])
    grow.CreateFaceVertexIndicesAttr([0, 1, 2])
    grow.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    grow.GetPointsAttr().Set([(5, 5, -4), (6, 5, -4), (6, 6, -4)], 0.5)
    grow.GetPointsAttr().Set([(5, 5, -4), (6, 5, -4), (6, 7, -4), (9, 9, -4)], 1.5)  # a point more
    stage.GetRootLayer().Save()
    data = translate_stage(str(path))
    assert sum("point count changes during the shutter" in w for w in data.warnings) == 1, data.warnings
    # The stretching quad deforms; the growing triangle stands at the frame.
    assert sum(p.get("motion_positions") is not None for p in data.prototypes) == 1