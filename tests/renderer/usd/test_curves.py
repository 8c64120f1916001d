"""BasisCurves (issue 11 item 9b) render as tubes whose projected width is the authored
`widths`: a straight curve of width W and length S seen across its axis covers W * S of
the film plane (alpha summed over the image), checked to 1.5 % from two view directions (a
tube vertex and a facet facing the camera: the widest and narrowest views of the 16-sided
tube, +0.6 % and -1.3 % by construction); the negative control requires the same check to
fail for a curve 4 % wider, the smallest error it detects in both views. The expected coverage is
the rectangle W x S (the tube's round caps are open), so it comes from the width alone."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, UsdGeom

from tessera_renderer import load_scene
from usd_fixtures import add_camera, add_render_settings, new_stage

RES = 160
D = 100.0          # camera distance
FOCAL, APERTURE = 500.0, 10.0  # the film sees APERTURE / FOCAL * D = 2 units across at the curve
FRAME = APERTURE / FOCAL * D
TOL = 0.015


def _coverage(tmp_path, width, roll_deg, name, basis=None):
    stage = new_stage(tmp_path / f"{name}.usda")
    curve = UsdGeom.BasisCurves.Define(stage, "/Hair")
    if basis is None:
        curve.CreateTypeAttr(UsdGeom.Tokens.linear)
        pts = [(-0.6, 0, 0), (0.6, 0, 0)]
    else:  # a cubic bspline along x: straight, its ends at the outer controls' 1/6-2/3-1/6 mix
        curve.CreateTypeAttr(UsdGeom.Tokens.cubic)
        curve.CreateBasisAttr(basis)
        pts = [(-0.9, 0, 0), (-0.6, 0, 0), (-0.2, 0, 0), (0.2, 0, 0), (0.6, 0, 0), (0.9, 0, 0)]
    curve.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    curve.CreateCurveVertexCountsAttr([len(pts)])
    curve.CreateWidthsAttr([width])
    curve.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    UsdGeom.Xformable(curve.GetPrim()).AddRotateXOp().Set(roll_deg)  # roll about its own axis
    curve.CreateDisplayColorAttr([Gf.Vec3f(0.5, 0.5, 0.5)])
    cam = add_camera(stage, "/Cam", (0, 0, D), focal=FOCAL, haperture=APERTURE, vaperture=APERTURE)
    add_render_settings(stage, cam, (RES, RES))
    stage.GetRootLayer().Save()
    scene = load_scene(tmp_path / f"{name}.usda")
    img = scene.render_tile(0, 0, RES, RES, spp=16, max_depth=1)
    return float(img[..., 3].astype(np.float64).mean()) * FRAME * FRAME, scene


@pytest.mark.parametrize("roll", [0.0, 180.0 / 16])  # a vertex, then a facet, facing the camera
def test_linear_curve_covers_its_width_times_its_length(tmp_path, roll):
    width, length = 0.3, 1.2
    area, scene = _coverage(tmp_path, width, roll, "c")
    assert abs(area / (width * length) - 1) < TOL, area / (width * length)
    assert scene.num_triangles > 0 and not any("BasisCurves" in w for w in scene.warnings), scene.warnings
    # Control: 4 % wider fails the same check.
    wider, _ = _coverage(tmp_path, width * 1.04, roll, "w")
    assert abs(wider / (width * length) - 1) >= TOL


def test_cubic_bspline_follows_its_limit_ends(tmp_path):
    # A uniform cubic B-spline starts at (p0 + 4 p1 + p2) / 6 and ends at (p3 + 4 p4 + p5) / 6:
    # x from -0.6 - 0.0667 = -0.6167 to 0.6167, so a length of 1.2333 (closed form).
    width = 0.3
    length = 2 * (0.9 + 4 * 0.6 + 0.2) / 6
    area, _ = _coverage(tmp_path, width, 0.0, "b", basis=UsdGeom.Tokens.bspline)
    assert abs(area / (width * length) - 1) < TOL, area / (width * length)
    # Control: drawn through the control points (length 1.8) the coverage is far off.
    assert abs(area / (width * 1.8) - 1) > 5 * TOL
