"""UsdLux ShapingAPI (issue 11 item 7) through USD -> render, against closed forms.

A point light (SphereLight treatAsPoint) at height H points straight down (its -Z); a
narrow camera looks straight down at one floor point at the angle theta off the light's
axis. The Lambertian floor shows a/pi * I f(theta) cos(theta) / d^2 there, so the ratio of
the shaped to the unshaped render at the same point is the shaping factor f(theta) alone,
which UsdLux defines in closed form:
    cone:   f = 0 beyond the cone angle; 1 - smoothstep(angle (1 - softness), angle, theta)
    focus:  f = lerp(focusTint, 1, |cos theta|^focus)
    IES:    f = the profile's candela at theta over its peak (normalize off).
A delta light on a flat floor has no noise beyond the pixel footprint (< 1e-4 here), so
every ratio is checked to 0.5 %; each test's negative control runs the same check on a
light perturbed by the smallest change it must detect (2 % in the factor, or the cone
edge moved 1 degree past the point) and requires it to fail."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from tessera_renderer import SceneError, load_scene
from usd_fixtures import add_camera, add_render_settings, new_stage

H, RADIUS, L, ALBEDO = 2.0, 0.05, 800.0, 0.5
TOL = 0.005


def _render(tmp_path, theta_deg, name, kind="point", azimuth_deg=0.0, **shaping):
    """`azimuth_deg`: the floor point's horizontal angle about the light's axis, from its
    +X (world +X) toward its +Y (world -Z: the light is turned -90 degrees about X)."""
    r = H * math.tan(math.radians(theta_deg))
    x, z = r * math.cos(math.radians(azimuth_deg)), -r * math.sin(math.radians(azimuth_deg))
    stage = new_stage(tmp_path / f"{name}.usda")
    ground = UsdGeom.Mesh.Define(stage, "/Ground")
    ground.CreatePointsAttr([Gf.Vec3f(-50, 0, -50), Gf.Vec3f(-50, 0, 50), Gf.Vec3f(50, 0, 50), Gf.Vec3f(50, 0, -50)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    ground.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    ground.CreateDisplayColorAttr([Gf.Vec3f(ALBEDO, ALBEDO, ALBEDO)])  # Lambertian
    if kind == "rect":  # a small area light: the factor applies about its emitting normal
        # 0.02 wide: 0.3 degrees seen from the floor point, so that averaging the factor over
        # the light's extent stays far below the 0.5 % checked (a soft cone's edge curves).
        light = UsdLux.RectLight.Define(stage, "/Light")
        light.CreateWidthAttr(0.4 * RADIUS)
        light.CreateHeightAttr(0.4 * RADIUS)
    elif kind == "cylinder":  # along the light's X, emitting all round: shaped about its -Z
        # 0.005 long: 0.1 degree seen from the floor point (the factor's spread over the
        # light, and so the shaped render's sampling noise, stays far below 0.5 %).
        light = UsdLux.CylinderLight.Define(stage, "/Light")
        light.CreateRadiusAttr(0.025 * RADIUS)
        light.CreateLengthAttr(0.1 * RADIUS)
    elif kind == "distant":
        light = UsdLux.DistantLight.Define(stage, "/Light")
    else:
        light = UsdLux.SphereLight.Define(stage, "/Light")
        light.CreateRadiusAttr(RADIUS)
        light.CreateTreatAsPointAttr(True)
    light.AddTranslateOp().Set(Gf.Vec3d(0, H, 0))
    light.AddRotateXOp().Set(-90.0)  # local -Z to world -Y
    light.CreateIntensityAttr(L)
    if shaping:
        api = UsdLux.ShapingAPI.Apply(light.GetPrim())
        for key, value in shaping.items():
            if key == "ies":
                api.CreateShapingIesFileAttr(Sdf.AssetPath(value))
            elif key == "angle":
                api.CreateShapingConeAngleAttr(value)
            elif key == "softness":
                api.CreateShapingConeSoftnessAttr(value)
            elif key == "focus":
                api.CreateShapingFocusAttr(value)
            elif key == "tint":
                api.CreateShapingFocusTintAttr(Gf.Vec3f(*value))
            elif key == "angle_scale":
                api.CreateShapingIesAngleScaleAttr(value)
            elif key == "normalize":
                api.CreateShapingIesNormalizeAttr(value)
    cam = add_camera(stage, "/Cam", (x, 0.5, z), focal=1000.0, haperture=1.0, vaperture=1.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)  # look straight down
    add_render_settings(stage, cam, (4, 4))
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / f"{name}.usda")
    img = scene.render_tile(0, 0, 4, 4, spp=16, max_depth=1)
    return float(img[..., :3].astype(np.float64).mean()), scene.warnings


def _factor(tmp_path, theta, kind="point", azimuth=0.0, **shaping):
    shaped, warnings = _render(tmp_path, theta, "shaped", kind, azimuth, **shaping)
    plain, _ = _render(tmp_path, theta, "plain", kind, azimuth)
    return shaped / plain, warnings


def _close(measured, expected):
    return abs(measured - expected) <= TOL * max(expected, 1e-30) if expected > 0 else measured < 1e-6


def test_unshaped_point_light_follows_the_inverse_square_law(tmp_path):
    theta = 25.0
    value, _ = _render(tmp_path, theta, "plain")
    d = H / math.cos(math.radians(theta))
    intensity = L * math.pi * RADIUS ** 2  # UsdLux treatAsPoint: the sphere seen from afar
    expected = ALBEDO / math.pi * intensity * math.cos(math.radians(theta)) / d ** 2
    assert _close(value, expected), (value, expected)
    assert not _close(value, 1.02 * expected)  # control: a 2 % error is seen


@pytest.mark.parametrize("theta,expected", [(20.0, 1.0), (34.0, 1.0), (36.0, 0.0), (60.0, 0.0)])
def test_hard_cone_lights_inside_and_not_outside(tmp_path, theta, expected):
    f, warnings = _factor(tmp_path, theta, angle=35.0)
    assert _close(f, expected), (theta, f)
    assert not any("ShapingAPI" in w for w in warnings), warnings
    # Control: the cone edge moved one degree past the point flips the answer.
    moved = theta - 1.0 if expected else theta + 1.0
    g, _ = _factor(tmp_path, theta, angle=moved)
    assert not _close(g, expected), (theta, g)


@pytest.mark.parametrize("theta", [25.0, 30.0, 36.0])
def test_soft_cone_follows_the_smoothstep(tmp_path, theta):
    angle, softness = 40.0, 0.5
    start = angle * (1 - softness)
    t = min(max((theta - start) / (angle - start), 0.0), 1.0)
    expected = 1.0 - t * t * (3 - 2 * t)
    f, _ = _factor(tmp_path, theta, angle=angle, softness=softness)
    assert _close(f, expected), (theta, f, expected)
    assert not _close(f, expected * 1.02)


def test_focus_is_a_cosine_power_towards_the_tint(tmp_path):
    theta, focus, tint = 30.0, 3.0, (0.2, 0.2, 0.2)
    p = math.cos(math.radians(theta)) ** focus
    expected = tint[0] + (1 - tint[0]) * p
    f, _ = _factor(tmp_path, theta, focus=focus, tint=tint)
    assert _close(f, expected), (f, expected)
    assert not _close(f, expected * 1.02)


def _write_ies(path, candela_of, horizontal=(0,)):
    """A minimal LM-63-2002 file: one lamp, 10 vertical angles 0..90, the given horizontal
    angles; candela_of(vertical) or candela_of(vertical, horizontal) in degrees."""
    v = list(range(0, 91, 10))
    rows = [[candela_of(a) if len(horizontal) == 1 else candela_of(a, h) for a in v] for h in horizontal]
    path.write_text("IESNA:LM-63-2002\n[TEST] written for tessera's test\n[MANUFAC] none\nTILT=NONE\n"
                    f"1 -1 1 {len(v)} {len(horizontal)} 1 2 0 0 0\n1 1 100\n"
                    + " ".join(f"{a:g}" for a in v) + "\n" + " ".join(f"{h:g}" for h in horizontal) + "\n"
                    + "\n".join(" ".join(f"{c:.6f}" for c in row) for row in rows) + "\n")


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0])
def test_ies_profile_shapes_by_its_candela(tmp_path, theta):
    # cos-distributed candela (a Lambertian downlight); normalize off: candela over the peak.
    _write_ies(tmp_path / "down.ies", lambda a: 1500.0 * math.cos(math.radians(a)))
    expected = math.cos(math.radians(theta))
    f, warnings = _factor(tmp_path, theta, ies="./down.ies")
    assert _close(f, expected), (theta, f, expected)
    assert not any("IES" in w for w in warnings), warnings
    assert not _close(f, expected * 1.02)


@pytest.mark.parametrize("theta", [0.0, 30.0])
def test_ies_angle_scale_rescales_the_profile_about_180_degrees(tmp_path, theta):
    """UsdLux's shaping:ies:angleScale (RenderMan's profile scale): the light's angle theta
    reads the profile at (theta - 180) / (1 + angleScale) + 180 degrees. With 0.5 and the
    cos downlight: theta 0 reads 60 degrees (0.5), theta 30 reads 80 (0.174)."""
    _write_ies(tmp_path / "down.ies", lambda a: 1500.0 * math.cos(math.radians(a)))
    expected = math.cos(math.radians((theta - 180.0) / 1.5 + 180.0))
    f, warnings = _factor(tmp_path, theta, ies="./down.ies", angle_scale=0.5)
    assert _close(f, expected), (theta, f, expected)
    assert not any("angleScale" in w for w in warnings), warnings
    assert not _close(f, expected * 1.02)
    _, warnings = _factor(tmp_path, theta, ies="./down.ies", angle_scale=-1.0)
    assert any("angleScale at or below -1" in w for w in warnings), warnings


def _asymmetric(v, h):
    """A wall-washer: cos(v) down, brighter toward the light's +X (h 0) and +Y (h 90)."""
    return 1000.0 * math.cos(math.radians(v)) * (1 + 0.5 * math.cos(math.radians(h)) + 0.25 * math.sin(math.radians(h)))


FULL_CIRCLE = tuple(range(0, 361, 45))


@pytest.mark.parametrize("azimuth", [0.0, 90.0, 180.0, 270.0])
def test_ies_profile_varies_with_the_horizontal_angle(tmp_path, azimuth):
    """Type C photometry: horizontal angle 0 along the light's +X, 90 along its +Y. At
    vertical 30 degrees the factor is the candela over the file's peak (1000 (1 + 0.5^2 +
    0.25^2)^0.5 ... taken from the samples: the peak is the largest written value). The
    +Y / -Y pair (90 vs 270) tells the handedness apart; the controls are the averaged
    profile's factor (what Tessera did before) and the same file with that one horizontal
    column 2 % brighter, both of which must fail."""
    _write_ies(tmp_path / "wash.ies", _asymmetric, FULL_CIRCLE)
    peak = max(_asymmetric(v, h) for v in range(0, 91, 10) for h in FULL_CIRCLE)
    expected = _asymmetric(30.0, azimuth) / peak
    f, warnings = _factor(tmp_path, 30.0, azimuth=azimuth, ies="./wash.ies")
    assert _close(f, expected), (azimuth, f, expected)
    assert not any("IES" in w for w in warnings), warnings
    averaged = 1000.0 * math.cos(math.radians(30.0)) / peak
    assert not _close(f, averaged), (f, averaged)
    _write_ies(tmp_path / "wash.ies", lambda v, h: _asymmetric(v, h) * (1.02 if h == azimuth else 1.0), FULL_CIRCLE)
    g, _ = _factor(tmp_path, 30.0, azimuth=azimuth, ies="./wash.ies")
    assert not _close(g, expected), (azimuth, g, expected)


def test_an_azimuthal_ies_profile_travels_in_the_scene_blob(tmp_path):
    """The farm's workers read the translated blob: the same image, bit for bit."""
    from tessera_renderer.scene_blob import scene_from_blob, translate_to_blob

    _write_ies(tmp_path / "wash.ies", _asymmetric, FULL_CIRCLE)
    _render(tmp_path, 30.0, "wash", azimuth=90.0, ies="./wash.ies")
    local = load_scene(tmp_path / "wash.usda")
    remote = scene_from_blob(translate_to_blob(tmp_path / "wash.usda"))
    assert remote.data.ies_tables.shape == (1, 181, 73)
    a, b = (s.render_tile(0, 0, 4, 4, spp=4, max_depth=1) for s in (local, remote))
    np.testing.assert_array_equal(a, b)
    # Control: the same scene without its table renders differently.
    _render(tmp_path, 30.0, "plain", azimuth=90.0)
    assert not np.array_equal(load_scene(tmp_path / "plain.usda").render_tile(0, 0, 4, 4, spp=4, max_depth=1), a)


def test_ies_horizontal_symmetries_expand_to_the_full_circle(tmp_path):
    """LM-63's symmetric files (one angle, 0..90, 0..180) give the table of the full-circle
    file they abbreviate; an end angle the standard does not allow is an error."""
    from tessera_renderer.usd.light_shaping import IesError, ies_profile

    def table(name, candela_of, horizontal):
        _write_ies(tmp_path / name, candela_of, horizontal)
        return ies_profile((tmp_path / name).read_text(), False, lambda msg: None)

    def quadrant(v, h):  # symmetric about the 0-180 and the 90-270 planes
        return 800.0 * math.cos(math.radians(v)) * (1 + 0.5 * math.cos(math.radians(2 * h)))

    def bilateral(v, h):  # symmetric about the 0-180 plane only
        return 800.0 * math.cos(math.radians(v)) * (1 + 0.5 * math.cos(math.radians(h)))

    def round_(v, h=0):
        return 800.0 * math.cos(math.radians(v))

    for f, short in ((quadrant, (0, 45, 90)), (bilateral, (0, 45, 90, 135, 180)), (round_, (0,))):
        full, abbreviated = table("full.ies", f, FULL_CIRCLE), table("short.ies", f, short)
        assert np.allclose(abbreviated, full, atol=1e-6), f.__name__
    # Control: cut to 0..90, a profile without the quadrant symmetry gives another table.
    assert not np.allclose(table("q.ies", bilateral, (0, 45, 90)), table("b.ies", bilateral, FULL_CIRCLE), atol=1e-3)
    with pytest.raises(IesError, match="end at 120 degrees"):
        table("odd.ies", bilateral, (0, 60, 120))


def test_normalized_azimuthal_ies_has_a_mean_of_one_over_the_sphere(tmp_path):
    """shaping:ies:normalize: the factors are the candela over their mean over the sphere.
    For cos(v) (1 + 0.5 cos h + 0.25 sin h) on the lower hemisphere the mean is 1/4 of the
    peak-free amplitude (the h terms average out; the mean of cos v over the hemisphere is
    1/2, half the sphere emits): so at v 30, h 0 the factor is 6 cos 30 exactly. The file's
    10-degree vertical and 45-degree horizontal samples are interpolated linearly, which
    the closed form does not see: measured, that leaves the factor 0.3 % high; the check
    allows 1 %, and the control (a 2 % brighter expectation) must fail it."""
    _write_ies(tmp_path / "wash.ies", _asymmetric, FULL_CIRCLE)
    expected = 6.0 * math.cos(math.radians(30.0))
    stage_factor, _ = _factor(tmp_path, 30.0, ies="./wash.ies", normalize=True)
    assert abs(stage_factor / expected - 1) < 0.01, (stage_factor, expected)
    assert not abs(stage_factor / (1.02 * expected) - 1) < 0.01


@pytest.mark.parametrize("theta, shaping", [(30.0, {"focus": 3.0, "tint": (0.2, 0.2, 0.2)}),
                                            (25.0, {"angle": 30.0, "softness": 0.5}),
                                            (35.0, {"angle": 30.0})])
def test_rect_light_is_shaped_about_its_emitting_normal(tmp_path, theta, shaping):
    """A RectLight with ShapingAPI: the shaped over the unshaped render is the same
    closed-form factor as for a point light, to 0.5 % (a 2 % error fails)."""
    t = math.radians(theta)
    if "focus" in shaping:
        expected = 0.2 + 0.8 * math.cos(t) ** 3.0
    elif "softness" in shaping:
        x = (theta - 30.0 * 0.5) / (30.0 - 15.0)
        expected = 1 - x * x * (3 - 2 * x)
    else:
        expected = 0.0  # beyond the cone
    f, warnings = _factor(tmp_path, theta, "rect", **shaping)
    assert _close(f, expected), (f, expected)
    assert not any("Shaping" in w or "shaping" in w for w in warnings), warnings
    if expected > 0:
        assert not _close(f, expected * 1.02)


@pytest.mark.parametrize("theta, shaping, expected", [(20.0, {"angle": 35.0}, 1.0), (36.0, {"angle": 35.0}, 0.0),
                                                      (25.0, {"angle": 30.0, "softness": 0.5}, None)])
def test_cylinder_light_is_shaped_about_its_axis(tmp_path, theta, shaping, expected):
    """A CylinderLight's normals turn around it, so its ShapingAPI cone is about the light's
    -Z (as Omniverse defines it), the same closed form as for a point light, to 0.5 %; shaped
    about each emitting normal instead, most of the side would be cut at 20 degrees (the
    factor would fall well below 1), and ignored (before) the light would pass 36 degrees.
    The soft edge is checked across the cylinder: along it the light spans 0.1 degree of
    a factor falling 34 % per degree at 25 degrees, which moves the mean factor by -0.36 %
    (converged, 1024 spp), too close to the bound for a 16-sample render."""
    if expected is None:
        x = (theta - 15.0) / 15.0
        expected = 1 - x * x * (3 - 2 * x)
    for azimuth in (0.0, 90.0) if "softness" not in shaping else (90.0,):  # along the cylinder, across it
        f, warnings = _factor(tmp_path, theta, "cylinder", azimuth, **shaping)
        assert _close(f, expected), (azimuth, f, expected)
        assert not any("haping" in w for w in warnings), warnings
        if expected > 0:
            assert not _close(f, expected * 1.02)
    # Control: the cone edge moved one degree past the point flips a hard cone's answer.
    if "softness" not in shaping:
        g, _ = _factor(tmp_path, theta, "cylinder", angle=theta - 1.0 if expected else theta + 1.0)
        assert not _close(g, expected), g


def test_distant_light_is_shaped_along_its_direction(tmp_path):
    """A DistantLight emits along its -Z only: a cone (of any angle) and focus leave it as it
    is, an IES profile scales it by its vertical-0 candela over the peak: 0.5 for a
    profile peaking at 30 degrees. Checked to 0.5 % (a delta light: no noise); the control
    is a profile whose axis value is 2 % higher."""
    for shaping in ({"angle": 10.0}, {"focus": 4.0, "tint": (0.1, 0.1, 0.1)}):
        f, warnings = _factor(tmp_path, 20.0, "distant", **shaping)
        assert _close(f, 1.0), (shaping, f)
        assert not any("haping" in w for w in warnings), warnings
    _write_ies(tmp_path / "batwing.ies", lambda a: 1000.0 * (0.5 + 0.5 * math.sin(math.radians(3 * a))))
    f, warnings = _factor(tmp_path, 20.0, "distant", ies="./batwing.ies")
    assert _close(f, 0.5), f
    assert not any("IES" in w or "haping" in w for w in warnings), warnings
    _write_ies(tmp_path / "batwing.ies",
               lambda a: 1000.0 * (0.51 if a == 0 else 0.5 + 0.5 * math.sin(math.radians(3 * a))))
    g, _ = _factor(tmp_path, 20.0, "distant", ies="./batwing.ies")
    assert not _close(g, 0.5), g


def test_ies_files_are_sandboxed_and_bad_ones_warn(tmp_path):
    (tmp_path / "bad.ies").write_text("IESNA:LM-63-2002\nTILT=NONE\n1 2 3\n")
    _, warnings = _render(tmp_path, 10.0, "badies", ies="./bad.ies")
    assert any("IES profile './bad.ies' cannot be read" in w for w in warnings), warnings
    _, warnings = _render(tmp_path, 10.0, "missing", ies="./none.ies")
    assert any("IES profile './none.ies' is missing" in w for w in warnings), warnings
    with pytest.raises(SceneError, match="outside"):
        _render(tmp_path, 10.0, "escape", ies="../../etc/passwd")


def test_a_shaped_sphere_light_is_a_shaped_point_with_one_note(tmp_path):
    """Omniverse writes spot lights as SphereLights with a radius and ShapingAPI."""
    stage = new_stage(tmp_path / "spot.usda")
    light = UsdLux.SphereLight.Define(stage, "/Spot")
    light.CreateRadiusAttr(0.1)
    UsdLux.ShapingAPI.Apply(light.GetPrim()).CreateShapingConeAngleAttr(20.0)
    UsdGeom.Sphere.Define(stage, "/Ball")
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / "spot.usda", default_light=False)
    assert len(scene.data.sphere_lights) == 0 and len(scene.data.point_lights) == 1
    assert scene.data.point_lights[0][6] == 1.0  # shaped
    assert math.isclose(scene.data.point_lights[0][10], math.radians(20.0), rel_tol=1e-6)
    assert sum("shaped SphereLights" in w for w in scene.warnings) == 1


def test_a_cone_of_zero_degrees_emits_nothing_and_the_fallback_is_a_hemisphere(tmp_path):
    f, _ = _factor(tmp_path, 0.5, angle=0.0)
    assert _close(f, 0.0), f
    # ShapingAPI applied with nothing authored: the schema's 90-degree cone lights the floor.
    g, _ = _factor(tmp_path, 60.0, focus=0.0)
    assert _close(g, 1.0), g
