"""NurbsPatch (tessellated) and Points (spheres of their widths), each against a closed
form: a rational quadratic arc lies on its circle, a B-spline patch over linearly placed
control points is their plane (linear precision), and spheres seen by an orthographic
camera cover n pi r^2 of the frame."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, Vt

from tessera import render
from tessera_renderer.usd import translate_stage
from tessera_renderer.usd.census import take_census
from tessera_renderer.usd.bundle import Limits
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, emission_only, new_stage

RADIUS, HEIGHT = 1.5, 2.0


def _quarter_cylinder(stage, path="/World/Patch", orientation=None):
    """The quarter cylinder x^2 + y^2 = RADIUS^2, x, y >= 0, 0 <= z <= HEIGHT, written as
    DCC tools write an exact circular arc: a rational quadratic in u (weights 1, 1/sqrt 2, 1)
    and linear in v."""
    s = math.sqrt(0.5)
    arc, weights = [(1, 0), (1, 1), (0, 1)], [1.0, s, 1.0]
    points, w = [], []
    for z in (0.0, HEIGHT):  # u fastest
        for (x, y), wk in zip(arc, weights):
            points.append(Gf.Vec3f(RADIUS * x, RADIUS * y, z))
            w.append(wk)
    patch = UsdGeom.NurbsPatch.Define(stage, path)
    patch.CreateUVertexCountAttr(3)
    patch.CreateVVertexCountAttr(2)
    patch.CreateUOrderAttr(3)
    patch.CreateVOrderAttr(2)
    patch.CreateUKnotsAttr([0, 0, 0, 1, 1, 1])
    patch.CreateVKnotsAttr([0, 0, 1, 1])
    patch.CreatePointsAttr(points)
    patch.CreatePointWeightsAttr(Vt.DoubleArray(w))
    if orientation:
        patch.CreateOrientationAttr(orientation)
    return patch


def _world(data):
    return data.positions.astype(np.float64) + np.asarray(data.world_offset)


def test_a_rational_arc_patch_lies_on_its_cylinder_with_the_closed_form_area(tmp_path):
    stage = new_stage(tmp_path / "p.usda")
    _quarter_cylinder(stage)
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "p.usda"))
    assert not any("NurbsPatch" in w for w in data.warnings), data.warnings
    p = _world(data)
    tri = p[data.indices]
    radius = np.hypot(p[:, 0], p[:, 1])
    assert np.abs(radius - RADIUS).max() < 1e-5  # float32 positions; the arc itself is exact
    assert p[:, 2].min() == pytest.approx(0.0, abs=1e-6) and p[:, 2].max() == pytest.approx(HEIGHT, abs=1e-6)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    # Chords of 8 pieces over 90 degrees: area ratio sin(t/2)/(t/2) with t = pi/16, 0.9984;
    # the linear direction is one piece.
    closed_form = math.pi / 2 * RADIUS * HEIGHT
    assert area == pytest.approx(closed_form, rel=2e-3)
    assert area != pytest.approx(closed_form * 1.01, rel=2e-3)  # the check sees 1 %
    # The front face is dP/du x dP/dv: outward, here; leftHanded turns it inward.
    centroid = tri.mean(axis=1)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.einsum("ij,ij->i", face, np.c_[centroid[:, :2], np.zeros(len(centroid))]) > 0
    assert outward.all()
    n = data.shading_normals.reshape(-1, 3)
    corner = tri.reshape(-1, 3)
    radial = np.c_[corner[:, :2], np.zeros(len(corner))] / RADIUS
    assert np.einsum("ij,ij->i", n / np.linalg.norm(n, axis=1, keepdims=True), radial).min() > 0.999

    flipped = new_stage(tmp_path / "l.usda")
    _quarter_cylinder(flipped, orientation=UsdGeom.Tokens.leftHanded)
    flipped.GetRootLayer().Save()
    left = translate_stage(str(tmp_path / "l.usda"))
    lt = _world(left)[left.indices]
    lface = np.cross(lt[:, 1] - lt[:, 0], lt[:, 2] - lt[:, 0])
    assert (np.einsum("ij,ij->i", lface, np.c_[lt.mean(axis=1)[:, :2], np.zeros(len(lt))]) < 0).all()


def test_a_cubic_patch_with_interior_knots_reproduces_its_control_plane(tmp_path):
    """Linear precision: control points at the knots' Greville abscissae on the plane
    z = 0.3 x - 0.2 y give exactly that plane, spanning the corner control points."""
    order, n = 4, 6
    knots = np.array([0, 0, 0, 0, 0.3, 0.45, 1, 1, 1, 1], float)  # non-uniform interior knots
    greville = np.array([knots[i + 1:i + order].mean() for i in range(n)])
    stage = new_stage(tmp_path / "c.usda")
    patch = UsdGeom.NurbsPatch.Define(stage, "/World/Plane")
    points = [Gf.Vec3f(4 * gu, 3 * gv, 0.3 * 4 * gu - 0.2 * 3 * gv) for gv in greville for gu in greville]
    patch.CreateUVertexCountAttr(n)
    patch.CreateVVertexCountAttr(n)
    patch.CreateUOrderAttr(order)
    patch.CreateVOrderAttr(order)
    patch.CreateUKnotsAttr(list(knots))
    patch.CreateVKnotsAttr(list(knots))
    patch.CreatePointsAttr(points)
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "c.usda"))
    p = _world(data)
    assert np.abs(p[:, 2] - (0.3 * p[:, 0] - 0.2 * p[:, 1])).max() < 1e-5
    assert (p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()) == \
        pytest.approx((0.0, 4.0, 0.0, 3.0), abs=1e-5)
    # 3 knot spans a direction, 8 pieces each: a 25 x 25 vertex grid.
    assert len(data.indices) == 2 * 24 * 24


def test_a_broken_patch_is_named_and_skipped_and_broken_trim_curves_are_named(tmp_path):
    stage = new_stage(tmp_path / "b.usda")
    bad = _quarter_cylinder(stage, "/World/Bad")
    bad.CreateUKnotsAttr([0, 0, 1, 1])  # too few knots for 3 vertices of order 3
    trimmed = _quarter_cylinder(stage, "/World/Trimmed")
    trimmed.CreateTrimCurveCountsAttr([1])
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "b.usda"))
    assert any("/World/Bad: NurbsPatch skipped: knot counts 4 and 4" in w for w in data.warnings), data.warnings
    assert any("/World/Trimmed: NurbsPatch trim curves ignored (the untrimmed surface is rendered): trim curves: "
               "counts sum to 1 curves" in w for w in data.warnings), data.warnings
    assert len(data.indices) == 2 * 8 * 1  # the trimmed patch alone, untrimmed: 8 pieces of arc, 1 linear


SIDE, DISC = 2.0, 0.4  # a SIDE x SIDE square patch; a trim circle of radius DISC in (u, v)


def _trimmed_square(stage, loops):
    """A flat SIDE x SIDE bilinear patch over (u, v) in [0, 1]^2, trimmed by `loops`: each
    a list of curves (order, knots, homogeneous (u, v, w) points), as DCC tools write them."""
    patch = UsdGeom.NurbsPatch.Define(stage, "/World/Trimmed")
    patch.CreateUVertexCountAttr(2)
    patch.CreateVVertexCountAttr(2)
    patch.CreateUOrderAttr(2)
    patch.CreateVOrderAttr(2)
    patch.CreateUKnotsAttr([0, 0, 1, 1])
    patch.CreateVKnotsAttr([0, 0, 1, 1])
    patch.CreatePointsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(SIDE, 0, 0), Gf.Vec3f(0, SIDE, 0), Gf.Vec3f(SIDE, SIDE, 0)])
    curves = [c for loop in loops for c in loop]
    patch.CreateTrimCurveCountsAttr([len(loop) for loop in loops])
    patch.CreateTrimCurveOrdersAttr([order for order, _, _ in curves])
    patch.CreateTrimCurveVertexCountsAttr([len(points) for _, _, points in curves])
    patch.CreateTrimCurveKnotsAttr(Vt.DoubleArray([k for _, knots, _ in curves for k in knots]))
    patch.CreateTrimCurveRangesAttr([Gf.Vec2d(knots[order - 1], knots[-order]) for order, knots, _ in curves])
    patch.CreateTrimCurvePointsAttr([Gf.Vec3d(*p) for _, _, points in curves for p in points])
    return patch


def _circle(center, radius):
    """The exact circle as one rational quadratic curve of 9 points (4 quarter arcs),
    homogeneous: (u w, v w, w)."""
    s = math.sqrt(0.5)
    unit = [(1, 0, 1), (1, 1, s), (0, 1, 1), (-1, 1, s), (-1, 0, 1), (-1, -1, s), (0, -1, 1), (1, -1, s), (1, 0, 1)]
    points = [((center[0] + radius * x) * w, (center[1] + radius * y) * w, w) for x, y, w in unit]
    return (3, [0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 4], points)


def _area(data):
    tri = data.positions.astype(np.float64)[data.indices]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()


@pytest.mark.parametrize("hole", [False, True])
def test_a_trimmed_disc_has_the_area_of_its_circle(tmp_path, hole):
    """A square patch trimmed by a circle of radius 0.4 in (u, v), 0.8 on the 2 x 2 patch:
    its area is pi r^2 to 0.5 % (measured 0.06 %); with a square outer loop around the
    circle the circle is a hole, area SIDE^2 - pi r^2. Negative control: a circle 1 %
    wider (2 % more area) fails the same check."""
    stage = new_stage(tmp_path / "trim.usda")
    circle = [_circle((0.5, 0.5), DISC)]
    square = [(2, [0, 0, 1, 2, 3, 4, 4], [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1), (0, 0, 1)])]
    _trimmed_square(stage, [square, circle] if hole else [circle])
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "trim.usda"))
    assert not any("NurbsPatch" in w for w in data.warnings), data.warnings
    disc = math.pi * (DISC * SIDE) ** 2
    expected = SIDE ** 2 - disc if hole else disc
    assert _area(data) == pytest.approx(expected, rel=0.005)
    wider = math.pi * (1.01 * DISC * SIDE) ** 2
    assert (SIDE ** 2 - wider if hole else wider) != pytest.approx(expected, rel=0.005)
    # Every kept triangle's centroid is where the trim says: inside the disc, or outside it.
    p = data.positions.astype(np.float64) + np.asarray(data.world_offset)
    centroid = p[data.indices].mean(axis=1)[:, :2]
    r = np.linalg.norm(centroid - SIDE * 0.5, axis=1)
    assert ((r > DISC * SIDE) if hole else (r < DISC * SIDE)).all()


def _points_scene(path, widths):
    """Four glowing points at z = 0 before a black backdrop, an orthographic camera 4 units
    across looking down -z: the image mean is the covered fraction of the frame."""
    stage = new_stage(path)
    glow = add_material(stage, "/Looks/Glow", diffuse=(0, 0, 0), emissive=(1, 1, 1))
    black = add_material(stage, "/Looks/Black", diffuse=(0, 0, 0))
    pts = UsdGeom.Points.Define(stage, "/World/Points")
    pts.CreatePointsAttr([Gf.Vec3f(x, y, 0) for x in (-0.9, 0.9) for y in (-0.9, 0.9)])
    pts.CreateWidthsAttr(widths)
    from pxr import UsdShade
    UsdShade.MaterialBindingAPI.Apply(pts.GetPrim()).Bind(glow)
    add_mesh(stage, "/World/Back", [(-50, -50, -40), (50, -50, -40), (50, 50, -40), (-50, 50, -40)], [4],
             [0, 1, 2, 3], black)
    cam = add_camera(stage, "/Cam", (0.0, 0.0, 8.0), focal=50.0, haperture=40.0, vaperture=40.0)
    cam.CreateProjectionAttr("orthographic")
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 1000.0))
    add_render_settings(stage, cam, (96, 96))
    emission_only(stage)
    stage.GetRootLayer().Save()


def test_points_are_spheres_of_their_widths(tmp_path):
    """Coverage 4 pi r^2 / 16 to 1 % (anti-aliased edges at 64 spp); a control with widths
    2 % larger (coverage +4 %) must fail the same check."""
    widths = [0.8, 0.6, 1.0, 0.7]
    expected = sum(math.pi * (w / 2) ** 2 for w in widths) / 16.0

    def coverage(ws):
        _points_scene(tmp_path / "pts.usda", ws)
        return float(render(tmp_path / "pts.usda", spp=64, integrator="path", variance=False).rgb.mean())

    assert coverage(widths) == pytest.approx(expected, rel=0.01)
    assert coverage([1.02 * w for w in widths]) != pytest.approx(expected, rel=0.01)


def test_points_without_widths_are_one_across_and_bad_points_are_named(tmp_path):
    stage = new_stage(tmp_path / "w.usda")
    pts = UsdGeom.Points.Define(stage, "/World/Points")
    pts.CreatePointsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(float("nan"), 0, 0), Gf.Vec3f(3, 0, 0)])
    stage.GetRootLayer().Save()
    data = translate_stage(str(tmp_path / "w.usda"))
    assert any("/World/Points: 1 points with a NaN/Inf position" in w for w in data.warnings), data.warnings
    p = _world(data)
    first = p[p[:, 0] < 1.5]
    # The polyhedron is scaled to the sphere's area: its vertices sit a little outside r = 0.5.
    r = np.linalg.norm(first, axis=1)
    assert 0.5 <= r.min() and r.max() < 0.5 * 1.02
    assert len(data.indices) == 2 * 224


def test_the_census_counts_points_and_patches():
    from pxr import Usd

    stage = Usd.Stage.CreateInMemory()
    pts = UsdGeom.Points.Define(stage, "/P")
    pts.CreatePointsAttr([Gf.Vec3f(i, 0, 0) for i in range(1000)])
    _quarter_cylinder(stage, "/N")
    census = take_census(stage, Limits())
    # The patch's bound: 8 x 8 pieces for each of 5 x 3 knot intervals (6 and 4 knots).
    assert census.triangles == 1000 * 224 + 2 * 8 * 8 * 5 * 3
    with pytest.raises(Exception, match="more than 100000 triangles"):
        take_census(stage, Limits(triangles=100_000))
