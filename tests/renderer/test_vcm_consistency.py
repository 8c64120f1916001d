"""vcm is consistent: its error keeps falling with iterations, because the merging radius
shrinks (r_i = r_1 i^((alpha - 1) / 2)); with a fixed radius it would stop at the kernel's
bias (a plateau).

The scene makes the kernel's bias large and its limit exact: a point light of intensity I
at height h over a Lambertian floor (albedo a), seen straight down; a floor point at
distance rho from the light's foot has radiance a / pi * I h / (h^2 + rho^2)^(3/2). With a
first radius of 0.3 h the disk kernel underestimates the peak by ~6 % (3/4 (r/h)^2), and
with many light paths merging carries almost all of the light, so the image's relMSE
against the closed form is dominated by that bias and falls only as the radius does. The
floor's light is direct, which vcm leaves to its connections by default (docs/integrators.md,
"Direct light is not merged"): the test merges it (`direct_merging` = 1) to give the
schedule a large, exactly known kernel bias to remove.

Check: the relMSE of the running mean after 4, 16 and 64 iterations falls by at least a
tenth per 4x more iterations (measured: 9.7e-4, 7.8e-4, 4.6e-4; the bias^2 ~ r^4 ~
i^(-1/2) at alpha = 0.75, plus the falling variance). Negative control: alpha = 0.9999
(a practically fixed radius) must fail the same check, and end at over twice the error
(measured: 1.8e-3, 2.4e-3, 2.5e-3: a plateau at the kernel's bias).
"""
from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from tessera_renderer import load_scene
from usd_fixtures import add_camera, add_mesh, add_render_settings, new_stage
from vcm_helpers import render_iteration

pytestmark = pytest.mark.slow

H_LIGHT, ALBEDO, LE, BULB_RADIUS, CAM_HEIGHT, TAN_HALF, RES = 1.0, 0.5, 1000.0, 0.1, 0.5, 0.5, 16
# UsdLux treatAsPoint: the radiant intensity of the sphere seen from afar, I = L pi r^2
# (docs/scene-translation.md, "Lights").
INTENSITY = LE * np.pi * BULB_RADIUS ** 2
CHECKPOINTS = (4, 16, 64)


def write_scene(path):
    stage = new_stage(path)
    floor = add_mesh(stage, "/Floor", [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)], [4], [0, 1, 2, 3])
    floor.CreateDisplayColorAttr([Gf.Vec3f(ALBEDO, ALBEDO, ALBEDO)])
    bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
    bulb.CreateTreatAsPointAttr(True)
    bulb.CreateIntensityAttr(LE)
    bulb.CreateRadiusAttr(BULB_RADIUS)
    bulb.AddTranslateOp().Set(Gf.Vec3d(0, H_LIGHT, 0))
    cam = add_camera(stage, "/Cam", (0, CAM_HEIGHT, 0), focal=10.0, haperture=20.0 * TAN_HALF,
                     vaperture=20.0 * TAN_HALF)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)  # look straight down
    add_render_settings(stage, cam, (RES, RES))
    stage.GetRootLayer().Save()
    return load_scene(path)


def closed_form() -> np.ndarray:
    """Per pixel, the radiance at the floor point its centre sees (the floor's variation
    within a pixel adds < 1e-3 relative, far below the kernel's bias)."""
    s = TAN_HALF * CAM_HEIGHT
    c = ((np.arange(RES) + 0.5) / RES * 2 - 1) * s
    x, z = np.meshgrid(c, c)
    return ALBEDO / np.pi * INTENSITY * H_LIGHT / (H_LIGHT ** 2 + x * x + z * z) ** 1.5


def relmse_curve(scene, alpha: float) -> list[float]:
    params = {"light_paths": 50000, "radius": 0.3, "alpha": alpha, "direct_merging": 1}
    expected = closed_form()
    total, out = np.zeros_like(expected), []
    for k in range(CHECKPOINTS[-1]):
        img = render_iteration(scene, "vcm", k, spp=1, seed=3, max_depth=1, params=params)
        total += img[..., :3].mean(axis=2)
        if k + 1 in CHECKPOINTS:
            mean = total / (k + 1)
            out.append(float(np.mean((mean - expected) ** 2 / expected ** 2)))
    return out


def falls(curve: list[float]) -> bool:
    return all(b < 0.9 * a for a, b in zip(curve, curve[1:]))


def test_relmse_keeps_falling_with_iterations(tmp_path):
    scene = write_scene(tmp_path / "pointfloor.usda")
    shrinking = relmse_curve(scene, 0.75)
    fixed = relmse_curve(scene, 0.9999)
    print(f"relMSE after {CHECKPOINTS} iterations: alpha 0.75 {shrinking}, fixed radius {fixed}")
    assert falls(shrinking), shrinking
    assert not falls(fixed), fixed  # the control: a fixed radius plateaus at the kernel's bias
    assert fixed[-1] > 2 * shrinking[-1]
