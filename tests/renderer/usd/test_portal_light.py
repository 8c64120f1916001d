"""PortalLight (UsdLux) through the whole route: stage -> light_rows["portal"] -> blob ->
core. A constant dome seen from the floor of a closed box through a rectangular hole in its
ceiling, with a portal in the hole: the floor's irradiance is L times the hole's projected
solid angle (Lambert's polygon formula), and the portal reaches it with far less noise per
sample than the dome alone."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, UsdLux

from tessera_renderer import load_scene
from tessera_renderer.scene_blob import scene_data_from_blob, scene_data_to_blob
from tessera_renderer.usd import translate_stage

from usd_fixtures import add_camera, add_mesh, add_render_settings, new_stage

L_DOME = 2.0
FLOOR_ALBEDO = 0.8
HEIGHT = 2.0  # the box: [-1, 1] x [0, HEIGHT] x [-1, 1]
HOLE = (0.3, 0.2)  # the hole's half-width (x) and half-depth (z), centred above the origin
RES = 16


def _quad(x0, x1, z0, z1, y):
    return [(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]


def _box_with_hole(tmp_path, name, hole=HOLE, portal=True, dome=True):
    """The box (black inside but for its floor), the hole in its ceiling, the dome above and,
    if `portal`, a PortalLight filling the hole; a camera at the box's centre looks straight
    down at the origin through a field of view 0.01 wide (a footprint of 0.01 on the floor)."""
    path = tmp_path / f"{name}.usda"
    stage = new_stage(path)
    # displayColor: pure Lambertian surfaces (a UsdPreviewSurface's specular lobe would
    # reflect the opening straight up into the camera).
    floor = add_mesh(stage, "/Floor", _quad(-1, 1, -1, 1, 0.0), [4], [0, 1, 2, 3], double_sided=True)
    floor.CreateDisplayColorAttr([Gf.Vec3f(FLOOR_ALBEDO)])
    hx, hz = hole
    ceiling = [_quad(-1, -hx, -1, 1, HEIGHT), _quad(hx, 1, -1, 1, HEIGHT),
               _quad(-hx, hx, -1, -hz, HEIGHT), _quad(-hx, hx, hz, 1, HEIGHT)]
    walls = [[(-1, 0, -1), (1, 0, -1), (1, HEIGHT, -1), (-1, HEIGHT, -1)],
             [(-1, 0, 1), (1, 0, 1), (1, HEIGHT, 1), (-1, HEIGHT, 1)],
             [(-1, 0, -1), (-1, 0, 1), (-1, HEIGHT, 1), (-1, HEIGHT, -1)],
             [(1, 0, -1), (1, 0, 1), (1, HEIGHT, 1), (1, HEIGHT, -1)]]
    for k, q in enumerate(ceiling + walls):
        add_mesh(stage, f"/Box/Q{k}", q, [4], [0, 1, 2, 3], double_sided=True).CreateDisplayColorAttr([Gf.Vec3f(0.0)])
    if dome:
        UsdLux.DomeLight.Define(stage, "/Dome").CreateIntensityAttr(L_DOME)
    if portal:
        p = UsdLux.PortalLight.Define(stage, "/Portal")
        p.CreateWidthAttr(2 * hx)
        p.CreateHeightAttr(2 * hz)
        p.AddTranslateOp().Set(Gf.Vec3d(0, HEIGHT, 0))
        p.AddRotateXOp().Set(-90.0)  # its light travels along its -Z: down into the box
    cam = add_camera(stage, "/Cam", translate=(0, 1.0, 0), focal=50.0, haperture=0.5, vaperture=0.5)
    cam.AddRotateXOp().Set(-90.0)  # looks along -Y
    add_render_settings(stage, cam, (RES, RES))
    stage.Save()
    return path


def _projected_solid_angle(p, n, corners) -> float:
    """Lambert's formula: 1/2 sum over edges of angle(v_i, v_i+1) n . unit(v_i x v_i+1)."""
    v = [np.subtract(c, p) / np.linalg.norm(np.subtract(c, p)) for c in corners]
    total = 0.0
    for a, b in zip(v, v[1:] + v[:1]):
        cross = np.cross(a, b)
        total += math.acos(np.clip(np.dot(a, b), -1.0, 1.0)) * np.dot(n, cross / np.linalg.norm(cross))
    return abs(0.5 * total)


def _expected_pixel(hole=HOLE) -> float:
    """The floor's radiance at the origin: rho / pi x E, E = L x projected solid angle."""
    hx, hz = hole
    corners = [(-hx, HEIGHT, -hz), (hx, HEIGHT, -hz), (hx, HEIGHT, hz), (-hx, HEIGHT, hz)]
    return FLOOR_ALBEDO / math.pi * L_DOME * _projected_solid_angle((0, 0, 0), (0, 1, 0), corners)


def _render(path, spp, seed=0):
    rgba = load_scene(path, default_light=False).render_tile(0, 0, RES, RES, spp=spp, seed=seed, max_depth=4,
                                                             integrator="path", sampler="independent")
    return rgba[..., 0].astype(np.float64)


def _within(pixels, expected, tolerance) -> bool:
    return abs(pixels.mean() / expected - 1.0) < tolerance


def test_the_closed_form_itself():
    # A small hole far above: projected solid angle -> area / distance^2.
    corners = [(-0.01, 10, -0.01), (0.01, 10, -0.01), (0.01, 10, 0.01), (-0.01, 10, 0.01)]
    assert _projected_solid_angle((0, 0, 0), (0, 1, 0), corners) == pytest.approx(4e-4 / 100, rel=1e-5)
    # The whole hemisphere (a huge square close above) projects to pi.
    big = [(-1e4, 1e-3, -1e4), (1e4, 1e-3, -1e4), (1e4, 1e-3, 1e4), (-1e4, 1e-3, 1e4)]
    assert _projected_solid_angle((0, 0, 0), (0, 1, 0), big) == pytest.approx(math.pi, rel=1e-5)


def test_floor_below_a_portal_sees_dome_radiance_times_projected_solid_angle(tmp_path):
    """Smallest error detected: 1 % of the floor's radiance (the mean over 256 pixels x 16
    samples has a standard error near 0.1 %). Negative control: the hole and its portal 2 %
    wider must fail the same check against the original's closed form."""
    expected = _expected_pixel()
    pixels = _render(_box_with_hole(tmp_path, "portal"), spp=16)
    assert _within(pixels, expected, 0.01), (pixels.mean(), expected)
    assert pixels.std() / math.sqrt(pixels.size) < 0.003 * expected  # the check has the power it claims
    wider = (HOLE[0] * 1.02, HOLE[1])
    assert _expected_pixel(wider) / expected - 1.0 > 0.015
    perturbed = _render(_box_with_hole(tmp_path, "wider", hole=wider), spp=16)
    assert not _within(perturbed, expected, 0.01), (perturbed.mean(), expected)
    assert _within(perturbed, _expected_pixel(wider), 0.01)


def test_portal_lowers_error_per_sample_against_the_dome_alone(tmp_path):
    """relMSE per pixel at 8 samples, portal against the dome alone (same box, same hole):
    the dome's samples find the hole with probability of its solid angle over 4 pi."""
    expected = _expected_pixel()
    portal = _render(_box_with_hole(tmp_path, "portal"), spp=8, seed=1)
    dome = _render(_box_with_hole(tmp_path, "dome", portal=False), spp=8, seed=1)
    rel_mse_portal = np.mean((portal - expected) ** 2) / expected ** 2
    rel_mse_dome = np.mean((dome - expected) ** 2) / expected ** 2
    print(f"relMSE at 8 spp: portal {rel_mse_portal:.3g}, dome alone {rel_mse_dome:.3g}, "
          f"ratio {rel_mse_dome / rel_mse_portal:.3g}")
    assert rel_mse_dome > 20 * rel_mse_portal


def test_portal_light_as_usdlux_writes_it(tmp_path):
    """A DomeLight and a PortalLight authored with UsdLux: one portal row (centre, half
    edges, outward normal Cross(u, v) = +Y toward the dome) that survives the scene blob."""
    data = translate_stage(str(_box_with_hole(tmp_path, "usd")), camera_relative=False)
    row = np.asarray(data.light_rows["portal"])
    assert row.shape == (1, 9)
    center, u, v = row[0, :3], row[0, 3:6], row[0, 6:9]
    assert np.allclose(center, (0, HEIGHT, 0), atol=1e-6)
    # Local X (width) stays X; local Y (height) turns to -Z under the -90 degree turn about X.
    assert np.allclose(u, (HOLE[0], 0, 0), atol=1e-6) and np.allclose(v, (0, 0, -HOLE[1]), atol=1e-6)
    assert np.allclose(np.cross(u, v) / np.linalg.norm(np.cross(u, v)), (0, 1, 0), atol=1e-6)
    again = scene_data_from_blob(scene_data_to_blob(data))
    assert np.array_equal(again.light_rows["portal"], row)


def test_portal_without_a_dome_warns(tmp_path):
    data = translate_stage(str(_box_with_hole(tmp_path, "alone", dome=False)))
    assert any("without a DomeLight" in w for w in data.warnings), data.warnings


@pytest.mark.parametrize("integrator", ["bdpt", "light"])
def test_light_path_integrators_refuse_portals_by_name(tmp_path, integrator):
    scene = load_scene(_box_with_hole(tmp_path, "refuse"), default_light=False)
    with pytest.raises(ValueError, match=f"the {integrator} integrator.*portal"):
        scene.render_tile(0, 0, 2, 2, width=RES, height=RES, spp=1, integrator=integrator,
                          splats=np.zeros((RES, RES, 3), np.int64))


def test_auto_pilot_leaves_out_integrators_that_start_paths_at_lights(tmp_path):
    from tessera_base.integrators import integrators, pilot_candidates

    assert load_scene(_box_with_hole(tmp_path, "pilot"), default_light=False).kind_without_light_paths() == "portal"
    assert load_scene(_box_with_hole(tmp_path, "no-portal", portal=False)).kind_without_light_paths() is None
    tracing = {i["name"] for i in integrators() if i["traces_light_paths"]}
    assert {"light", "bdpt", "vcm", "sppm", "photon", "photon_direct"} <= tracing
    kept = pilot_candidates(mirrors_or_glass=True, noise_target=True, delta_caustics=False, light_paths=False)
    assert "path" in kept and not tracing & set(kept)
    assert tracing & set(pilot_candidates(mirrors_or_glass=True, noise_target=True, delta_caustics=False))
