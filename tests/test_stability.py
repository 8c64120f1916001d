"""Numerical stability under stress: far from the origin, at tiny and huge scales, with
degenerate, sliver, coincident and thin geometry, grazing angles, extreme roughness and
ior, and extreme light values, through every integrator.

Every render here goes through tessera_renderer.Scene.render_tile, which raises
NonFiniteSampleError when the renderer's counter of NaN/Inf samples (RenderStats) or of
rejected splats is not zero, so each render is also a check that it is zero; the pixels
are checked for NaN/Inf on top. Scenes are built as SceneData arrays (no USD) so that the
geometry is exactly what the test says. The lit plane's answer is analytic: a Lambertian
plane of albedo rho under a distant light of irradiance E at incidence theta has radiance
rho E cos(theta) / pi, in every pixel, from every integrator.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tessera_renderer import Scene
from tessera_renderer.film import resolve_image
from tessera_renderer.usd_scene import PARAM_KEYS, CameraDesc, SceneData

INTEGRATORS = ("path", "light", "bdpt", "local", "whitted")
DETERMINISTIC = ("path", "local", "whitted")   # exact on the lit plane: one delta light, no bounce back
RES = 24
RHO, E = 0.5, 2.0
LIGHT = np.array([1.0, 0.5, -1.0]) / np.linalg.norm([1.0, 0.5, -1.0])  # travel direction
PLANE_RADIANCE = RHO * E * abs(LIGHT[2]) / math.pi


# ------------------------------------------------------------------ scene building
class Builder:
    """Triangles, materials and lights in one coordinate frame; `build` applies
    p -> p * scale + offset to geometry, camera and point/sphere lights alike."""

    def __init__(self):
        self.points: list[np.ndarray] = []
        self.tris: list[tuple[int, int, int]] = []
        self.tri_material: list[int] = []
        self.albedo: list[tuple[float, float, float]] = []
        self.emission: list[tuple[float, float, float]] = []
        self.params: list[dict] = []
        self.distant: list[list[float]] = []
        self.spheres: list[list[float]] = []
        self.camera = dict(origin=(0.0, 0.0, 1.5), right=(1, 0, 0), up=(0, 1, 0), forward=(0, 0, -1))

    def material(self, albedo=RHO, emission=0.0, **preview) -> int:
        self.albedo.append((albedo,) * 3 if np.isscalar(albedo) else tuple(albedo))
        self.emission.append((emission,) * 3 if np.isscalar(emission) else tuple(emission))
        self.params.append(preview)
        return len(self.albedo) - 1

    def triangles(self, points, tris, material: int) -> None:
        base = len(self.points)
        self.points += [np.asarray(p, np.float64) for p in points]
        self.tris += [(a + base, b + base, c + base) for a, b, c in tris]
        self.tri_material += [material] * len(tris)

    def quad(self, center, u, v, material: int) -> None:
        c, u, v = (np.asarray(x, np.float64) for x in (center, u, v))
        self.triangles([c - u - v, c + u - v, c + u + v, c - u + v], [(0, 1, 2), (0, 2, 3)], material)

    def box(self, lo, hi, material: int) -> None:
        """A closed, watertight box: 8 shared corners, 12 triangles."""
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        pts = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
        quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
        self.triangles(pts, [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], material)

    def build(self, offset: float = 0.0, scale: float = 1.0, res: int = RES, fov_tan: float = 0.5) -> Scene:
        def place(p):
            return np.asarray(p, np.float64) * scale + offset
        rows = len(self.albedo)
        params = {}
        if any(self.params):
            defaults = dict(specular_color=(0.0, 0.0, 0.0), metallic=0.0, roughness=0.5, ior=1.5,
                            clearcoat=0.0, clearcoat_roughness=0.01, opacity=1.0, opacity_threshold=0.0,
                            use_specular_workflow=0.0)
            for key in PARAM_KEYS:
                if key == "preview_surface":
                    params[key] = np.array([bool(p) for p in self.params])
                else:
                    params[key] = np.array([p.get(key, defaults[key]) for p in self.params], np.float32)
        cam = CameraDesc(origin=tuple(place(self.camera["origin"])), right=self.camera["right"],
                         up=self.camera["up"], forward=self.camera["forward"], horizontal_aperture=2 * fov_tan,
                         vertical_aperture=2 * fov_tan, focal_length=1.0, source="test")
        spheres = [[*place(s[:3]), s[3] * scale, *s[4:]] for s in self.spheres]
        data = SceneData(
            positions=place(np.array(self.points).reshape(-1, 3)).astype(np.float32),
            indices=np.asarray(self.tris, np.uint32).reshape(-1, 3),
            triangle_material=np.asarray(self.tri_material, np.uint32),
            albedo=np.asarray(self.albedo, np.float32).reshape(rows, 3),
            emission=np.asarray(self.emission, np.float32).reshape(rows, 3),
            two_sided_emission=np.zeros(rows, bool),
            sphere_lights=np.asarray(spheres, np.float32).reshape(-1, 7),
            camera=cam, resolution=(res, res), resolution_from_stage=True, material_params=params,
            distant_lights=np.asarray(self.distant, np.float32).reshape(-1, 7))
        return Scene(data)


def render(scene: Scene, integrator: str, spp: int = 4, seed: int = 0) -> np.ndarray:
    """The full image's RGB. NonFiniteSampleError (the renderer's counter) fails the test."""
    w, h = scene.width, scene.height
    if integrator in ("light", "bdpt"):
        splats = np.zeros((h, w, 3), np.int64)
        rgba = scene.render_tile(0, 0, w, h, spp=spp, seed=seed, threads=2, integrator=integrator,
                                 splats=splats)
        rgb = resolve_image(rgba, splats, w * h * spp, scene.splat_exponent)[..., :3]
    else:
        rgb = scene.render_tile(0, 0, w, h, spp=spp, seed=seed, threads=2, integrator=integrator)[..., :3]
    assert np.isfinite(rgb).all(), f"{integrator}: {int((~np.isfinite(rgb)).sum())} non-finite values"
    return rgb


def lit_plane(light=LIGHT, occluder: bool = False) -> Builder:
    b = Builder()
    m = b.material()
    b.quad((0, 0, 0), (4, 0, 0), (0, 4, 0), m)
    if occluder:  # a square 0.5 above the plane whose shadow the camera partly sees
        b.quad((0, 0, 0.5), (0.3, 0, 0), (0, 0.3, 0), m)
    b.distant.append([*light, 0.0, E, E, E])
    return b


def assert_within_noise(image: np.ndarray, reference: np.ndarray, what: str, sigmas: float = 6.0) -> None:
    """Mean of the image (and of each quarter) equals the reference's within `sigmas`
    standard errors (from the pixel spread of both), for the noisy integrators."""
    h, w = image.shape[:2]
    for ys, xs in ((slice(None), slice(None)), (slice(0, h // 2), slice(0, w // 2)),
                   (slice(0, h // 2), slice(w // 2, None)), (slice(h // 2, None), slice(0, w // 2)),
                   (slice(h // 2, None), slice(w // 2, None))):
        a, b = image[ys, xs].reshape(-1, 3), reference[ys, xs].reshape(-1, 3)
        se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b)) + 1e-6 * np.abs(b).mean()
        diff = np.abs(a.mean(axis=0) - b.mean(axis=0))
        assert (diff <= sigmas * se + 2e-3 * np.abs(b.mean(axis=0))).all(), \
            f"{what}: mean {a.mean(axis=0)} vs {b.mean(axis=0)} (se {se})"


# ------------------------------------------------------------------ far away, tiny, huge
# Rays leave a surface by the error bound of their hit point (math.h OffsetRayOrigin), which
# grows with the triangle's own coordinates: a few float32 ulps at 1e5 (0.0078 units), so the
# occluder 0.5 above the plane there still casts its shadow. (An offset proportional to |p|,
# 1e-5 (1 + max |p|), jumped that gap; this test caught it.)
PLACEMENTS = [dict(offset=1e3), dict(offset=1e5), dict(scale=1e-3), dict(scale=1e4),
              dict(offset=1e5, scale=1e3)]
NOISY_HERE = ("path", "light", "bdpt")  # path: the bounce under the occluder is random


def _placement_id(p: dict) -> str:
    return ",".join(f"{k}={v:g}" for k, v in p.items()) or "unit"


@pytest.fixture(scope="module")
def shadow_reference() -> dict[str, np.ndarray]:
    scene = lit_plane(occluder=True).build()
    return {i: render(scene, i, spp=64 if i in NOISY_HERE else 4) for i in INTEGRATORS}


def test_shadow_reference_is_what_the_geometry_says(shadow_reference):
    """Not vacuous: the unit-scale image has lit plane, the occluder, interreflection
    under it and a visible shadow."""
    v = shadow_reference["local"][..., 0] / PLANE_RADIANCE
    assert (np.abs(v - 1) < 1e-5).mean() > 0.7 and (v == 0).sum() >= 20
    bounced = shadow_reference["path"][..., 0] > shadow_reference["local"][..., 0] + 1e-3
    assert bounced.sum() >= 10  # light bounced between the plane and the occluder


@pytest.mark.parametrize("placement,integrator", [
    pytest.param(p, i, id=f"{i}-{_placement_id(p)}",
                 )
    for p in PLACEMENTS for i in INTEGRATORS])
def test_offset_and_scale_leave_the_image_unchanged(shadow_reference, placement, integrator):
    """The lit plane with an occluder, moved far from the origin or scaled: the same image.
    local and whitted (deterministic here): pixel for pixel, up to a few pixels on the
    shadow's and the occluder's edges (float32 rounding moves an edge by a fraction of a
    pixel), and the same number of shadow pixels within 4. path, light and bdpt: the means of
    the image and of its quarters within noise."""
    image = render(lit_plane(occluder=True).build(**placement), integrator,
                   spp=64 if integrator in NOISY_HERE else 4)
    reference = shadow_reference[integrator]
    if integrator not in NOISY_HERE:
        differ = ~np.isclose(image, reference, rtol=1e-3, atol=1e-6).all(axis=2)
        shadow, shadow_ref = int((image[..., 0] == 0).sum()), int((reference[..., 0] == 0).sum())
        # Nothing may change away from an edge (of the occluder or its shadow) of the
        # reference: a changed interior pixel is a lost shadow or a leak.
        value = reference[..., 0]
        padded = np.pad(value, 1, mode="edge")
        window = np.stack([padded[dy:dy + RES, dx:dx + RES] for dy in range(3) for dx in range(3)])
        edge = ~np.isclose(window.min(axis=0), window.max(axis=0), rtol=1e-3, atol=1e-6)
        assert not (differ & ~edge).any(), f"pixels changed away from edges: {np.argwhere(differ & ~edge)[:5]}"
        if placement.get("offset", 0.0) < 1e5:
            assert differ.sum() <= 0.02 * RES * RES and abs(shadow - shadow_ref) <= 4, (
                f"{int(differ.sum())} of {RES * RES} pixels changed; shadow pixels {shadow_ref} -> {shadow}")
        # At 1e5, float32 holds coordinates to 0.0078 (5 % of a pixel here), and the
        # occluder's axis-aligned edges lie on rows of sample positions, so whole edge rows
        # may flip; only the edges may move.
    else:
        assert_within_noise(image, reference, f"{integrator} {placement}")


# ------------------------------------------------------------------ shadow acne
@pytest.mark.parametrize("incidence", [0.0, 45.0, 80.0, 89.0])
@pytest.mark.parametrize("placement", [dict(), dict(offset=1e3), dict(offset=1e5), dict(scale=1e-3),
                                       dict(scale=1e4)], ids=lambda p: ",".join(f"{k}={v:g}" for k, v in p.items()) or "unit")
def test_no_shadow_acne_on_a_lit_plane(incidence, placement):
    """Every pixel of the lit plane equals rho E cos(theta) / pi (no dark pixel from a
    shadow ray hitting its own surface), for light at 0 to 89 degrees from the normal."""
    theta = math.radians(incidence)
    light = np.array([math.sin(theta), 0.0, -math.cos(theta)])
    scene = lit_plane(light).build(**placement)
    expected = RHO * E * math.cos(theta) / math.pi
    for integrator in DETERMINISTIC:
        v = render(scene, integrator)[..., 0] / expected
        dark = float((v < 0.99).mean())
        assert dark == 0.0, f"{integrator}: {dark:.1%} dark pixels (min {v.min():.3g})"
        np.testing.assert_allclose(v, 1.0, rtol=1e-4, err_msg=integrator)
    for integrator in ("light", "bdpt"):
        v = render(scene, integrator, spp=16)[..., 0] / expected
        assert abs(v.mean() - 1.0) < 6 * v.std() / math.sqrt(v.size) + 2e-3, integrator


@pytest.mark.parametrize("size", [
    4.0, 100.0,
    # The hit point's error grows with the triangle's vertices (1e3-1e4 away), not with |p|
    # (near the origin): an offset proportional to |p| left 81 % and 96 % of these dark.
    1e3, 1e4])
def test_no_shadow_acne_on_a_large_tilted_plane(size):
    """A plane tilted 30 degrees, `size` across, seen from 1.5 away near the origin."""
    a = math.radians(30.0)
    n = np.array([0.0, -math.sin(a), math.cos(a)])
    v_axis = np.array([0.0, math.cos(a), math.sin(a)])
    b = Builder()
    b.quad((0.1, 0.2, 0.0), (size, 0, 0), v_axis * size, b.material())
    light = -0.8 * n + np.array([0.6, 0.0, 0.0])
    light /= np.linalg.norm(light)
    b.distant.append([*light, 0.0, E, E, E])
    b.camera = dict(origin=tuple(np.array([0.1, 0.2, 0.0]) + 1.5 * n), right=(1, 0, 0), up=tuple(v_axis),
                    forward=tuple(-n))
    scene = b.build()
    expected = RHO * E * abs(float(light @ n)) / math.pi
    for integrator in DETERMINISTIC:
        v = render(scene, integrator)[..., 0] / expected
        assert (v < 0.99).mean() == 0.0, f"{integrator}: {(v < 0.99).mean():.1%} dark pixels"


@pytest.mark.parametrize("elevation", [5.0, 1.0, 0.1])
def test_grazing_camera_rays(elevation):
    """The camera looking at the plane almost edge-on: pixels that hit it have the analytic
    value, the others are black sky, one row of pixels straddles the horizon; nothing NaN."""
    b = lit_plane(np.array([0.0, 0.0, -1.0]))
    e = math.radians(elevation)
    b.points = [p * np.array([1e3, 1e3, 1.0]) for p in b.points]  # a large plane
    b.camera = dict(origin=(0.0, -10.0, 10.0 * math.tan(e) + 1e-3), right=(1, 0, 0),
                    up=(0, -math.sin(e), math.cos(e)), forward=(0, math.cos(e), -math.sin(e)))
    scene = b.build()
    expected = RHO * E / math.pi
    for integrator in INTEGRATORS:
        v = render(scene, integrator)[..., 0] / expected
        if integrator in DETERMINISTIC:
            assert (v > 0).mean() > 0.2, integrator
            full = np.isclose(v, 1.0, rtol=1e-4)
            partial = ~full & (v != 0)
            assert partial.sum() <= RES and (v <= 1 + 1e-4).all(), integrator
            rows = np.flatnonzero(full.any(axis=1))
            assert full[rows[0] + 1:].all(), f"{integrator}: dark pixels below the horizon"


# ------------------------------------------------------------------ awkward geometry
def test_degenerate_and_sliver_triangles():
    """Zero-area triangles (repeated and collinear corners), needle slivers, and the same
    as emitters, in the lit plane's scene: every integrator stays finite, and the plane's
    pixels keep their value where no sliver covers them."""
    b = lit_plane()
    m = b.material()
    glow = b.material(emission=5.0)
    p = np.array([0.1, 0.1, 0.2])
    for mat in (m, glow):
        b.triangles([p, p, p], [(0, 1, 2)], mat)                                     # a point
        b.triangles([p, p + (0.2, 0, 0), p + (0.4, 0, 0)], [(0, 1, 2)], mat)          # collinear
        b.triangles([p, p + (0.3, 0.1, 0), p + (0.3, 0.1, 0)], [(0, 1, 2)], mat)      # repeated corner
        b.triangles([p, p + (0.5, 0.1, 0), p + (0.5, 0.1 + 1e-7, 0)], [(0, 1, 2)], mat)  # needle
        b.triangles([p, p + (1e-6, 0, 0), p + (0, 1e-6, 0)], [(0, 1, 2)], mat)        # speck
    scene = b.build()
    for integrator in DETERMINISTIC:
        v = render(scene, integrator)[..., 0] / PLANE_RADIANCE
        assert np.median(v) == pytest.approx(1.0, rel=1e-4), integrator
    plane_only = np.isclose(render(scene, "path")[..., 0], PLANE_RADIANCE, rtol=1e-4)  # no sliver seen
    for integrator in ("light", "bdpt"):
        image = render(scene, integrator, spp=64)[..., 0][plane_only]
        assert abs(image.mean() / PLANE_RADIANCE - 1) < 6 * image.std() / math.sqrt(image.size) / PLANE_RADIANCE \
            + 0.01, integrator


def test_coincident_faces():
    """Two coplanar quads on top of each other (different albedo): each pixel shows one of
    them, lit, never dark or NaN."""
    b = lit_plane()
    other = b.material(albedo=0.25)
    b.quad((0, 0, 0), (4, 0, 0), (0, 4, 0), other)
    scene = b.build()
    for integrator in DETERMINISTIC:
        v = render(scene, integrator)[..., 0] / PLANE_RADIANCE
        assert np.isin(np.round(v, 4), (0.5, 1.0)).all(), integrator
    for integrator in ("light", "bdpt"):
        render(scene, integrator)


@pytest.mark.parametrize("thickness", [1e-2, 1e-4])
def test_thin_wall_lets_no_light_through(thickness):
    """A closed slab of the given thickness between the light (straight above) and the
    plane: the plane under it stays black; the slab's top is lit."""
    b = lit_plane(np.array([0.0, 0.0, -1.0]))
    m = b.material()
    b.box((-4, -4, 0.3), (4, 4, 0.3 + thickness), m)
    b.camera["origin"] = (0.0, 0.0, 0.2)  # between plane and slab, looking down
    scene = b.build()
    for integrator in INTEGRATORS:
        assert render(scene, integrator).max() == 0.0, integrator
    b.camera["origin"] = (0.0, 0.0, 1.5)
    v = render(b.build(), "local")[..., 0] / (RHO * E / math.pi)
    np.testing.assert_allclose(v, 1.0, rtol=1e-4)


# This caught a leak: bdpt let 1e-7 (unit scale) to 2 (1e3 from the origin) into the box
# through s = 2, t = 2 connections between an outside vertex and an inside one that
# rounding had put just past the neighbouring face's plane, near a shared edge. bdpt.cpp
# now drops connections whose sidedness is within the two hit points' error bounds.
@pytest.mark.parametrize("placement", [dict(), dict(offset=1e3), dict(scale=1e-3)], ids=_placement_id)
@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_watertight_box_with_the_lights_outside_is_black_inside(placement, integrator):
    """A closed box of shared-vertex triangles; a distant light and a bright sphere light
    outside. Seen from inside, the integrator sees exactly black."""
    b = Builder()
    m = b.material(albedo=0.9)
    b.box((-1, -1, -1), (1, 1, 1), m)
    b.distant.append([*LIGHT, 0.0, 1e3, 1e3, 1e3])
    b.spheres.append([3.0, 0.5, 0.2, 0.5, 1e4, 1e4, 1e4])
    b.camera = dict(origin=(0.2, -0.3, 0.1), right=(1, 0, 0), up=(0, 0, 1), forward=(0, 1, 0))
    scene = b.build(fov_tan=1.5, **placement)
    image = render(scene, integrator, spp=8)
    assert image.max() == 0.0, f"{integrator}: {int((image > 0).any(axis=2).sum())} lit pixels"
    # Not vacuous: the same box with one face missing lets light in.
    b.tris = b.tris[:-2]
    b.tri_material = b.tri_material[:-2]
    assert render(b.build(fov_tan=1.5, **placement), integrator, spp=8).max() > 0


# ------------------------------------------------------------------ materials at their limits
MATERIALS = {
    "mirror (roughness 0)": dict(metallic=1.0, roughness=0.0),
    "metal roughness 1": dict(metallic=1.0, roughness=1.0),
    "plastic roughness 0": dict(roughness=0.0),
    "plastic roughness 1e-4": dict(roughness=1e-4),
    "glass ior 1": dict(opacity=0.0, ior=1.0, roughness=0.0),
    "glass ior 1.0001": dict(opacity=0.0, ior=1.0001, roughness=0.0),
    "rough glass ior 1.0001": dict(opacity=0.0, ior=1.0001, roughness=1.0),
    "glass ior 1.5 roughness 1": dict(opacity=0.0, ior=1.5, roughness=1.0),
    "coat roughness 0": dict(clearcoat=1.0, clearcoat_roughness=0.0),
    "specular workflow ior 1": dict(use_specular_workflow=1.0, specular_color=(1.0, 1.0, 1.0), ior=1.0),
}


@pytest.mark.parametrize("name", MATERIALS)
def test_extreme_materials_stay_finite(name):
    """A tilted quad of the material over the lit plane, under a point-like sphere light
    and the distant light: no NaN/Inf from any integrator; energy bounded."""
    b = lit_plane()
    mat = b.material(albedo=0.8, preview_surface=True, **MATERIALS[name])
    b.quad((0, 0, 0.4), (0.5, 0, 0.2), (0, 0.5, 0), mat)
    b.spheres.append([0.3, 0.2, 1.0, 1e-3, 1e5, 1e5, 1e5])
    scene = b.build()
    for integrator in INTEGRATORS:
        image = render(scene, integrator)
        assert image.max() < 1e6, integrator


# ------------------------------------------------------------------ extreme lights
# light and bdpt splat camera connections into a fixed-point film (int64) so that any
# tiling sums exactly. With a fixed unit of 1 this caught both ends: emission 1e20 and
# above overflowed (2^39), 1e-9 and below rounded to black (2^-24). The unit is now a power
# of two from the scene's light power (Scene::splat_exponent), so every case here renders.


def _extreme_cases():
    for kind, size, value in (("sphere", 1e-5, 1e12), ("sphere", 1e-3, 1e20), ("sphere", 0.1, 1e-30),
                              ("sphere", 0.1, 1e30), ("quad", 0.05, 1e-30), ("quad", 0.05, 1e-9),
                              ("quad", 0.05, 1e-3), ("quad", 0.05, 1e3), ("quad", 0.05, 1e9),
                              ("quad", 0.05, 1e30)):
        for integrator in INTEGRATORS:
            yield pytest.param(kind, size, value, integrator,
                               id=f"{integrator}-{kind}-{size:g}-{value:g}")


@pytest.mark.parametrize("kind,size,value,integrator", list(_extreme_cases()))
def test_extreme_lights_are_finite_and_linear(kind, size, value, integrator):
    """A tiny very bright sphere light, or an emitting quad, from 1e-30 to 1e30 over the
    plane: finite (float32 holds 3.4e38), not black, and linear: twice the emission gives
    twice the image (the renderer's arithmetic is linear in emission, and the light
    selection does not depend on its scale)."""
    images_ = []
    for k in (1.0, 2.0):
        b = Builder()
        b.quad((0, 0, 0), (4, 0, 0), (0, 4, 0), b.material())
        if kind == "sphere":
            b.spheres.append([0.0, 0.0, 1.0, size, *(3 * [value * k])])
        else:
            b.quad((0, 0, 1.0), (size, 0, 0), (0, -size, 0), b.material(emission=value * k))  # faces -z
        images_.append(render(b.build(), integrator))
    one, two = images_
    assert one.max() > 0
    np.testing.assert_allclose(two, 2 * one, rtol=1e-5, atol=1e-37)
