"""The integrator matrix: every registered integrator on every analytic scene whose light
paths it sees, each region checked against a closed form (issue 46, "Make it impossible to
skip"; after pbrt-v4's integrators_test.cpp and Mitsuba 3's render tests).

Nothing here names an integrator. The cells come from the core's registry
(tessera_base.integrators): an integrator is checked on every scene whose light-path
classes (PATH_CLASSES, Heckbert's notation) it does not declare itself blind to
(IntegratorInfo::blind_to, with a reason) and whose quantity it estimates
(IntegratorInfo::estimates). A new integrator enters the matrix by being registered.

Each scene's expected values are closed forms, not renders: Le seen directly, the furnaces
Le / (1 - albedo), Lambert's polygon formula for rect and polygon (disk) lights, pi L (r/D)^2
cos(theta) for a sphere light, rho E cos(theta) / pi under a distant light, rho Ld under a
uniform dome, the Fresnel transmittance (1 - R) / (1 + R) of a glass slab (every internal
reflection summed), 1 - F (the form factor to an occluder) for ambient occlusion. The
variants put the rect-lit plane (and the AO plane) 1e6 from the origin (through USD, as a DCC
writes it: double transforms over float points), at 1e-3 and 1e3 scale, and with zero-area
triangles (plain and emissive) mixed in, which must not change a pixel's expected value.

The check (one per cell): K independent renders (seeds 1..K) through the production path
(tessera.local.render_image: scene passes, splats, progressive passes as a user gets them);
per region the mean of the K region means and its standard error. Every region must lie
within TOLERANCE of its closed form, with a relative standard error of at most MAX_SE, so
that an error of TOLERANCE + Z * se (at most 1.95 %) is detected with probability
Phi(Z) = 99.4 %, while a correct integrator fails a region only at TOLERANCE / se >= 4
standard errors. The samples per pixel are found per cell, not listed per integrator: a
pilot of K renders at PILOT_SPP measures the noise and the cell renders again with the spp
that noise needs (in steps, up to MAX_SPP; see measure). The negative control, in every cell: the check applied to
the same renders as if the light were brighter by the stated detectable error must fail
(radiance is linear in the emission, and test_negative_control_renders_the_brighter_light
renders that brighter light for one cell per integrator and finds exactly those values).

Cells that fail today are strict xfails in KNOWN_FAILURES below, with their measured
errors: remove a line when its fix is merged.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pytest

from tessera.local import render_image
from tessera_base import integrators
from tessera_base.protocol import RenderSettings
from tessera_renderer import _core, load_scene

from test_stability import Builder  # the scene builder of the stability tests (SceneData, no USD)
from usd_fixtures import add_material, add_render_settings, box_inward_faces, emission_only, new_stage

# ------------------------------------------------------------------ cells known to fail today
# (integrator, scene) -> why, with the measured worst region. A strict xfail: the cell
# must fail, so a fix shows up as an XPASS to remove here.
KNOWN_FAILURES: dict[tuple[str, str], str] = {}

K = 8                   # independent renders per cell
TOLERANCE = 0.012       # per region, relative
MAX_SE = 0.003          # largest relative standard error of a region's mean the check accepts
Z = 2.5                 # the stated power: an error of TOLERANCE + Z se is detected with Phi(Z)
# Light tracing needs the most: on the rect-lit plane a light path lands in a 4 x 4-pixel
# region about once in 13, and 8192 spp left a region's se at 0.35 %.
PILOT_SPP, MAX_SPP = 16, 32768
RES = 8                 # images of 8 x 8: four regions of 4 x 4 pixels unless a scene says
SUB = 6                 # closed forms averaged over SUB x SUB points of each pixel (box filter)
MAX_DEPTH = 64


# ------------------------------------------------------------------ closed forms
def polygon_irradiance(p: np.ndarray, n: np.ndarray, poly: np.ndarray, radiance: float) -> np.ndarray:
    """Irradiance at points p (N, 3) with normal n from a uniform Lambertian polygon (its
    corners in order, seen from p's side): Lambert's formula E = L/2 sum_i theta_i (n .
    unit(r_i x r_{i+1})) with r_i the corner directions and theta_i the angle between them."""
    r = poly[None, :, :] - p[:, None, :]
    r /= np.linalg.norm(r, axis=2, keepdims=True)
    r1 = np.roll(r, -1, axis=1)
    cross = np.cross(r, r1)
    theta = np.arccos(np.clip((r * r1).sum(axis=2), -1.0, 1.0))
    g = cross / np.linalg.norm(cross, axis=2, keepdims=True)
    return np.abs(0.5 * radiance * (theta * (g @ n)).sum(axis=1))


def fresnel_dielectric(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised reflectance of a smooth dielectric of relative ior eta, from outside."""
    sin_t = np.sqrt(np.maximum(0.0, 1 - cos_i ** 2)) / eta
    cos_t = np.sqrt(1 - sin_t ** 2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return rs ** 2, rp ** 2


# ------------------------------------------------------------------ scenes
@dataclass
class Case:
    """An analytic scene: the light-path classes its closed form needs, the quantity it
    checks, and `build(gain)`, which returns the scene with every light `gain` times as bright
    and the expected image (RES x RES, per pixel, averaged over the pixel) for gain 1."""
    name: str
    paths: tuple[str, ...]
    build: Callable[[float], tuple[object, np.ndarray]]
    quantity: str = "radiance"
    regions: tuple[tuple[slice, slice], ...] = ()


def quadrants(res: int = RES) -> tuple[tuple[slice, slice], ...]:
    h = res // 2
    return tuple((slice(y, y + h), slice(x, x + h)) for y in (0, h) for x in (0, h))


def camera_points(cam: dict, fov_tan: float, res: int = RES) -> tuple[np.ndarray, np.ndarray]:
    """Camera origin and unit ray directions (res, res, SUB * SUB, 3) through SUB x SUB points
    of each pixel, rows top to bottom (the image's up is the camera's up)."""
    o = np.asarray(cam["origin"], float)
    f, r, u = (np.asarray(cam[k], float) for k in ("forward", "right", "up"))
    s = (np.arange(SUB) + 0.5) / SUB
    px = (np.arange(res)[:, None] + s[None, :]).reshape(-1) / res * 2 - 1          # left to right
    py = 1 - (np.arange(res)[:, None] + s[None, :]).reshape(-1) / res * 2          # top to bottom
    d = f + fov_tan * (px[None, :, None] * r + py[:, None, None] * u)               # (res*SUB, res*SUB, 3)
    d = d.reshape(res, SUB, res, SUB, 3).transpose(0, 2, 1, 3, 4).reshape(res, res, SUB * SUB, 3)
    return o, d / np.linalg.norm(d, axis=-1, keepdims=True)


def plane_hits(cam: dict, fov_tan: float, z: float = 0.0) -> np.ndarray:
    o, d = camera_points(cam, fov_tan)
    t = (z - o[2]) / d[..., 2]
    return o + t[..., None] * d


DOWN = dict(right=(1, 0, 0), up=(0, 1, 0), forward=(0, 0, -1))
RHO = 0.5
# Small enough that light paths from a distant or dome light (started over the scene's
# bounding disk) mostly land in view; the view covers +-0.48 of it.
PLANE_HALF = 1.0


def _plane(b: Builder, albedo: float = RHO, half: float = PLANE_HALF) -> None:
    b.quad((0, 0, 0), (half, 0, 0), (0, half, 0), b.material(albedo=albedo))


# The rect-lit plane: the base of the placement and degenerate variants.
RECT = np.array([(-0.3, -0.4, 1.0), (-0.3, 0.4, 1.0), (0.7, 0.4, 1.0), (0.7, -0.4, 1.0)])  # faces -z
RECT_LE, CAM_Z, FOV = 3.0, 0.6, 0.8


def _rect_builder(gain: float) -> Builder:
    b = Builder()
    _plane(b)
    glow = b.material(albedo=0.0, emission=RECT_LE * gain)
    b.triangles(RECT, [(0, 1, 2), (0, 2, 3)], glow)
    b.camera = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    return b


def _rect_expected() -> np.ndarray:
    cam = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    p = plane_hits(cam, FOV).reshape(-1, 3)
    e = polygon_irradiance(p, np.array([0, 0, 1.0]), RECT, RECT_LE)
    return (RHO / math.pi * e).reshape(RES, RES, -1).mean(axis=2)


def rect_lit(gain: float, offset: float = 0.0, scale: float = 1.0):
    return _rect_builder(gain).build(offset=offset, scale=scale, res=RES, fov_tan=FOV), _rect_expected()


def rect_lit_degenerate(gain: float):
    """Zero-area triangles (a point, collinear corners, a repeated corner) in view and as
    emitters: they cover no pixel and emit nothing, so nothing may change."""
    b = _rect_builder(gain)
    plain, glow = b.material(), b.material(albedo=0.0, emission=5.0 * gain)
    for z, mat in ((0.3, plain), (0.8, glow), (0.0, glow)):
        p = np.array([0.05, -0.1, z])
        b.triangles([p, p, p], [(0, 1, 2)], mat)
        b.triangles([p, p + (0.2, 0, 0), p + (0.4, 0, 0)], [(0, 1, 2)], mat)
        b.triangles([p, p + (0.1, 0.1, 0), p + (0.1, 0.1, 0)], [(0, 1, 2)], mat)
    return b.build(res=RES, fov_tan=FOV), _rect_expected()


def _write_usd(b: Builder, path, offset: float, fov_tan: float):
    """The builder's triangles as a DCC writes a scene far from the origin: float points
    local to a double-precision translate of `offset`, UsdPreviewSurface materials without
    a specular lobe, the camera under the same transform."""
    from pxr import Gf, UsdGeom

    stage = new_stage(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    world = UsdGeom.Xform.Define(stage, "/World")
    world.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(offset, offset, offset))
    pts = np.array(b.points)
    tris = np.asarray(b.tris)
    for m in range(len(b.albedo)):
        sel = tris[np.asarray(b.tri_material) == m]
        if not len(sel):
            continue
        mat = add_material(stage, f"/Looks/M{m}", b.albedo[m], b.emission[m])
        from pxr import Sdf, UsdShade
        shader = UsdShade.Shader(stage.GetPrimAtPath(f"/Looks/M{m}/Surface"))
        for name, value in (("metallic", 0.0), ("roughness", 1.0), ("ior", 1.0)):
            shader.CreateInput(name, Sdf.ValueTypeNames.Float).Set(value)
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Mesh{m}")
        used = np.unique(sel)
        remap = {int(v): i for i, v in enumerate(used)}
        mesh.CreatePointsAttr([Gf.Vec3f(*map(float, pts[v])) for v in used])
        mesh.CreateFaceVertexCountsAttr([3] * len(sel))
        mesh.CreateFaceVertexIndicesAttr([remap[int(v)] for v in sel.reshape(-1)])
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")  # looks down its -z, up +y: DOWN
    cam.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*b.camera["origin"]))
    cam.CreateFocalLengthAttr(10.0)
    cam.CreateHorizontalApertureAttr(20.0 * fov_tan)
    cam.CreateVerticalApertureAttr(20.0 * fov_tan)
    add_render_settings(stage, cam, (RES, RES))
    emission_only(stage)
    stage.GetRootLayer().Save()
    return load_scene(path)


def rect_lit_far(gain: float, tmp) -> tuple:
    return _write_usd(_rect_builder(gain), tmp / f"far-{gain}.usda", 1e6, FOV), _rect_expected()


def emitters_seen(gain: float):
    """A one-sided emissive quad (Le 1) behind a sphere light (L 3) that fills the image's
    centre: the four corner regions see the quad, the centre region the sphere."""
    b = Builder()
    b.quad((0, 0, 0), (3, 0, 0), (0, 3, 0), b.material(albedo=0.0, emission=1.0 * gain))
    b.spheres.append([0.0, 0.0, 0.5, 0.3, 3.0 * gain, 3.0 * gain, 3.0 * gain])
    b.camera = dict(origin=(0.0, 0.0, 1.5), **DOWN)
    expected = np.ones((16, 16))
    expected[6:10, 6:10] = 3.0
    return b.build(res=16, fov_tan=0.5), expected


EMITTER_REGIONS = ((slice(0, 4), slice(0, 4)), (slice(0, 4), slice(12, 16)), (slice(12, 16), slice(0, 4)),
                   (slice(12, 16), slice(12, 16)), (slice(6, 10), slice(6, 10)))


def _furnace(gain: float, albedo: float, **preview):
    b = Builder()
    pts, _, idx = box_inward_faces((-1, -1, -1), (1, 1, 1))
    quads = np.asarray(idx).reshape(-1, 4)
    b.triangles(pts, [t for a, b_, c, d in quads for t in ((a, b_, c), (a, c, d))],
                b.material(albedo=albedo, emission=1.0 * gain, **preview))
    # The view keeps 0.6 from the walls: next event estimation toward an emitter that meets
    # the shading point's surface has unbounded variance (1 / r^2) without MIS.
    b.camera = dict(origin=(0.1, 0.2, 0.3), **DOWN)
    return b.build(res=RES, fov_tan=0.3), np.full((RES, RES), 1.0 / (1 - albedo))


def lambert_furnace(gain: float):
    return _furnace(gain, 0.5)


def mirror_furnace(gain: float):
    """Smooth metal (UsdPreviewSurface metallic 1, roughness 0) reflects its colour at every angle."""
    return _furnace(gain, 0.5, metallic=1.0, roughness=0.0)


def polygon_lit(gain: float, poly: np.ndarray, le: float):
    b = Builder()
    _plane(b)
    glow = b.material(albedo=0.0, emission=le * gain)
    b.triangles(poly, [(0, i, i + 1) for i in range(1, len(poly) - 1)], glow)
    b.camera = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    p = plane_hits(b.camera, FOV).reshape(-1, 3)
    e = polygon_irradiance(p, np.array([0, 0, 1.0]), poly, le)
    return b.build(res=RES, fov_tan=FOV), (RHO / math.pi * e).reshape(RES, RES, -1).mean(axis=2)


def disk_lit(gain: float):
    """A disk light as exporters tessellate it: a 48-gon of radius 0.5, 0.8 above the plane,
    off the view's centre, facing down (Lambert's formula is exact for the polygon)."""
    a = -np.arange(48) * 2 * math.pi / 48  # clockwise seen from above: faces -z
    poly = np.stack([0.2 + 0.5 * np.cos(a), 0.1 + 0.5 * np.sin(a), np.full(48, 0.8)], axis=1)
    return polygon_lit(gain, poly, 2.0)


def sphere_lit(gain: float):
    """A sphere light (radius 0.2, L 10) 1 above the plane, off centre: E = pi L (r/D)^2 cos
    at a point that sees the whole sphere (exact)."""
    c, r, le = np.array([0.3, 0.0, 1.0]), 0.2, 10.0
    b = Builder()
    _plane(b)
    b.spheres.append([*c, r, le * gain, le * gain, le * gain])
    b.camera = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    p = plane_hits(b.camera, FOV)
    v = c - p
    dist = np.linalg.norm(v, axis=-1)
    e = math.pi * le * (r / dist) ** 2 * (v[..., 2] / dist)
    return b.build(res=RES, fov_tan=FOV), (RHO / math.pi * e).mean(axis=2)


DISTANT = np.array([1.0, 0.5, -1.0]) / np.linalg.norm([1.0, 0.5, -1.0])  # travel direction


def distant_lit(gain: float):
    """rho E cos(theta) / pi everywhere (E 2, theta 35 degrees)."""
    b = Builder()
    _plane(b)
    b.distant.append([*DISTANT, 0.0, 2.0 * gain, 2.0 * gain, 2.0 * gain])
    b.camera = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    return b.build(res=RES, fov_tan=FOV), np.full((RES, RES), RHO * 2.0 * abs(DISTANT[2]) / math.pi)


def dome_lit(gain: float):
    """A uniform dome of radiance Ld = 1 over an unoccluded plane: E = pi Ld, radiance rho Ld."""
    scene_builder = Builder()
    _plane(scene_builder)
    scene_builder.camera = dict(origin=(0.0, 0.0, CAM_Z), **DOWN)
    scene = scene_builder.build(res=RES, fov_tan=FOV)
    data = scene.data
    data.dome_light = {"radiance": [gain] * 3, "texture": None, "world_to_light": np.eye(3).tolist(),
                       "path": "/Dome"}
    from tessera_renderer import Scene
    return Scene(data), np.full((RES, RES), RHO * 1.0)


def glass_slab(gain: float):
    """A smooth glass slab (ior 1.5, 0.2 thick) between the camera and an emissive plane (Le
    1): the camera sees Le times the slab's transmittance, every internal reflection summed,
    (1 - R) / (1 + R) per polarisation at the ray's incidence."""
    b = Builder()
    b.quad((0, 0, 0), (5, 0, 0), (0, 5, 0), b.material(albedo=0.0, emission=1.0 * gain))
    b.box((-4, -4, 0.4), (4, 4, 0.6), b.material(albedo=0.0, opacity=0.0, roughness=0.0, ior=1.5))
    b.camera = dict(origin=(0.0, 0.0, 1.5), **DOWN)
    fov = 0.15
    _, d = camera_points(b.camera, fov)
    rs, rp = fresnel_dielectric(-d[..., 2], 1.5)
    t = 0.5 * ((1 - rs) / (1 + rs) + (1 - rp) / (1 + rp))
    return b.build(res=RES, fov_tan=fov), t.mean(axis=2)


AO_SQUARE = np.array([(-0.4, -0.3, 0.5), (0.6, -0.3, 0.5), (0.6, 0.5, 0.5), (-0.4, 0.5, 0.5)])


def _ao_builder() -> Builder:
    b = Builder()
    _plane(b, half=10.0)  # the default max_distance, a tenth of the diameter (2.8), reaches the square
    b.triangles(AO_SQUARE, [(0, 1, 2), (0, 2, 3)], b.material())
    b.camera = dict(origin=(0.0, 0.0, 0.3), **DOWN)
    return b


def _ao_expected() -> np.ndarray:
    """The open fraction of the cosine-weighted hemisphere: 1 - F, F the point-to-square form
    factor (Lambert's formula with L = 1 over pi)."""
    cam = _ao_builder().camera
    p = plane_hits(cam, FOV).reshape(-1, 3)
    f = polygon_irradiance(p, np.array([0, 0, 1.0]), AO_SQUARE, 1.0) / math.pi
    return (1 - f).reshape(RES, RES, -1).mean(axis=2)


def ao_plane(gain: float, scale: float = 1.0):
    return _ao_builder().build(res=RES, fov_tan=FOV, scale=scale), _ao_expected()


CASES = [
    Case("emitters_seen", ("L E",), emitters_seen, regions=EMITTER_REGIONS),
    Case("lambert_furnace", ("L E", "L D E", "L D D+ E"), lambert_furnace),
    Case("mirror_furnace", ("L E", "L S+ E"), mirror_furnace),
    Case("rect_lit", ("L D E",), rect_lit),
    Case("disk_lit", ("L D E",), disk_lit),
    Case("sphere_lit", ("L D E",), sphere_lit),
    Case("distant_lit", ("Ld D E",), distant_lit),
    Case("dome_lit", ("Lenv D E",), dome_lit),
    Case("glass_slab", ("L E", "L S+ E"), glass_slab),
    Case("rect_lit_far_1e6", ("L D E",), lambda g, tmp=None: rect_lit_far(g, tmp)),
    Case("rect_lit_tiny_1e-3", ("L D E",), lambda g: rect_lit(g, scale=1e-3)),
    Case("rect_lit_huge_1e3", ("L D E",), lambda g: rect_lit(g, scale=1e3)),
    Case("rect_lit_degenerate", ("L D E",), rect_lit_degenerate),
    Case("ao_plane", (), ao_plane, quantity="ambient occlusion"),
    Case("ao_plane_tiny_1e-3", (), lambda g: ao_plane(g, scale=1e-3), quantity="ambient occlusion"),
    Case("ao_plane_huge_1e3", (), lambda g: ao_plane(g, scale=1e3), quantity="ambient occlusion"),
]
CASE_BY_NAME = {c.name: c for c in CASES}


# ------------------------------------------------------------------ the matrix from the registry
def blind(entry: dict, case: Case) -> list[str]:
    """Why `entry` (a registry dict) is not checked on `case`: [] if it is."""
    if entry.get("estimates", "radiance") != case.quantity:
        return [f"estimates {entry.get('estimates')}, not {case.quantity}"]
    return [f"{x['paths']}: {x['reason']}" for x in entry.get("blind_to", []) if x["paths"] in case.paths]


def cells() -> list[tuple[str, str]]:
    return [(i["name"], c.name) for i in integrators.integrators() for c in CASES if not blind(i, c)]


def matrix_params():
    out = []
    for name, case in cells():
        marks = [pytest.mark.slow]
        if (name, case) in KNOWN_FAILURES:
            marks.append(pytest.mark.xfail(strict=True, reason=KNOWN_FAILURES[(name, case)]))
        out.append(pytest.param(name, case, marks=marks, id=f"{name}-{case}"))
    return out


def build(case: Case, gain: float, tmp_path):
    if case.name.startswith("rect_lit_far"):
        return case.build(gain, tmp_path)
    return case.build(gain)


@dataclass
class Measured:
    spp: int
    means: np.ndarray            # (K, regions)
    expected: np.ndarray         # (regions,)
    seconds: float
    extra: dict = field(default_factory=dict)

    @property
    def rel(self) -> np.ndarray:
        return self.means.mean(axis=0) / self.expected - 1

    @property
    def rel_se(self) -> np.ndarray:
        return self.means.std(axis=0, ddof=1) / math.sqrt(len(self.means)) / self.expected

    @property
    def detectable(self) -> float:
        """The smallest relative error, up or down, the check detects with probability Phi(Z):
        TOLERANCE + Z se, rounded up to the next 0.1 % (an error of exactly TOLERANCE is a coin
        toss), from where the regions already lie. A method whose regions sit below their
        closed forms within TOLERANCE (radiosity's discretisation) needs a larger error
        upwards before a region leaves the band, one above it a larger error downwards."""
        rel = self.rel
        shift = max(-float(rel.max()), float(rel.min()))
        return math.floor((TOLERANCE + Z * float(self.rel_se.max()) + shift) * 1000 + 1) / 1000


def region_means(rgb: np.ndarray, regions) -> np.ndarray:
    grey = rgb[..., :3].astype(np.float64).mean(axis=-1)
    return np.array([grey[r].mean() for r in regions])


# Light paths (or photon paths) per batch of a progressive integrator (its registry entry's
# iteration_cap names the setting): the defaults (1e5) suit images of 1e5 pixels and would
# spend almost all of a 64-pixel cell's time on paths no pixel reads. A merging integrator
# (a radius schedule: sppm, vcm) estimates these scenes' direct light by next event
# estimation or connections, and its batches carry little of it. One without a radius
# schedule (photon_direct) estimates everything from its photons, and a camera sample looks
# up an iteration's whole map: with 512-photon batches the iterations' maps grew to 1e6
# photons and the rect-lit cell took 68 s (4096 spp), with 4096-photon batches 11 s (256
# spp), with 20000 21 s (128 spp).
BATCH_PATHS, FIXED_RADIUS_BATCH = 512, 4096


def settings_params(integrator: str) -> dict[str, float]:
    entry = next(i for i in integrators.integrators() if i["name"] == integrator)
    cap = entry.get("iteration_cap")
    if not cap:
        return {}
    return {cap["param"]: BATCH_PATHS if entry.get("merging_alpha") else FIXED_RADIUS_BATCH}


class ProductCache:
    """The scene-pass products of one cell's renders, by (seed, iteration). A product is a
    pure function of (scene, integrator, its settings, seed, iteration), not of the spp
    (Integrator::RunScenePass; the farm's bit-for-bit equality with local renders rests on
    it), so the renders at the next spp step reuse the pilot's: the images are the ones
    computed afresh, bit for bit, in fewer scene passes. Products that seeds 1 and 2 give
    bit for bit at an iteration (a deterministic solve: radiosity's, hybrid's) do not use
    the seed, and the other seeds reuse them, as renders() stops at two equal images.
    Measured on the module: hybrid's cells solved radiosity 16 times (8 seeds, pilot and
    step), now twice."""

    def __init__(self, scene):
        self.scene = scene
        self.products: dict[tuple[int, int], bytes] = {}

    def run(self, scene, settings, iteration, **kw):
        if scene is not self.scene:
            return self._original(scene, settings, iteration, **kw)
        key = (settings.seed, iteration)
        if key not in self.products:
            one, two = self.products.get((1, iteration)), self.products.get((2, iteration))
            if settings.seed > 2 and one is not None and one == two:
                return one
            self.products[key] = self._original(scene, settings, iteration, **kw)
        return self.products[key]

    def __enter__(self):
        from tessera import local
        self._original = local.run_scene_pass
        local.run_scene_pass = self.run
        return self

    def __exit__(self, *exc):
        from tessera import local
        local.run_scene_pass = self._original


def renders(scene, integrator: str, spp: int, regions, cache: ProductCache | None = None) -> np.ndarray:
    out = []
    for seed in range(1, K + 1):
        settings = RenderSettings(width=scene.width, height=scene.height, spp=spp, seed=seed,
                                  max_depth=MAX_DEPTH, integrator=integrator,
                                  integrator_params=settings_params(integrator))
        with cache or ProductCache(scene):
            image = render_image(scene, settings, threads=2, progress=False, variance=False).rgba
        out.append(region_means(image, regions))
        # Two seeds that give the same image bit for bit: the estimate does not depend on the
        # seed here (exact direct light from a delta light, a deterministic solve, emitters
        # seen directly), and more renders would repeat it.
        if seed == 2 and np.array_equal(out[0], out[1]):
            break
    return np.array(out)


def measure(integrator: str, case: Case, tmp_path, gain: float = 1.0, spp: int | None = None) -> Measured:
    started = time.perf_counter()
    scene, expected_image = build(case, gain, tmp_path)
    regions = case.regions or quadrants(expected_image.shape[0])
    expected = np.array([expected_image[r].mean() for r in regions])
    cache = ProductCache(scene)
    if spp is not None:
        return Measured(spp, renders(scene, integrator, spp, regions, cache), expected, time.perf_counter() - started)
    spp, means = PILOT_SPP, renders(scene, integrator, PILOT_SPP, regions, cache)
    while True:
        se = float((means.std(axis=0, ddof=1) / math.sqrt(len(means)) / expected).max())
        if se <= 0.8 * MAX_SE or spp >= MAX_SPP:
            break
        # The spp that brings the worst region's standard error to 60 % of MAX_SE (K renders
        # estimate it only to about 1 / sqrt(2 (K - 1)) = 27 %, and heavy tails, light
        # tracing's, hide in a small pilot: hence steps of at most 16 x), rounded up to a
        # multiple of PILOT_SPP: the next power of two spent up to twice the samples needed.
        need = spp * (se / (0.6 * MAX_SE)) ** 2
        step = int(min(MAX_SPP, spp * 16, max(spp * 2, PILOT_SPP * math.ceil(need / PILOT_SPP))))
        more = renders(scene, integrator, step, regions, cache)
        se_more = float((more.std(axis=0, ddof=1) / math.sqrt(len(more)) / expected).max())
        spp, means = step, more
        if 4 * PILOT_SPP <= step < MAX_SPP and se_more > 0.7 * se:
            # 4 x the samples or more left the noise where it was: it is the scene pass's
            # (one photon map or solve per iteration, fixed-spp renders run one), which no
            # number of samples lowers: the cell fails as too noisy to decide.
            return Measured(spp, means, expected, time.perf_counter() - started, {"floor": True})
    return Measured(spp, means, expected, time.perf_counter() - started)


def check(m: Measured, gain: float = 1.0) -> list[str]:
    """The regions that fail (empty: the cell passes): the error of the mean of `gain` times
    the measured values beyond TOLERANCE, or the standard error beyond MAX_SE."""
    rel = (1 + m.rel) * gain - 1
    bad = [f"region {k}: {rel[k]:+.2%} (se {m.rel_se[k]:.2%})" for k in range(len(rel)) if abs(rel[k]) > TOLERANCE]
    bad += [f"region {k}: se {m.rel_se[k]:.2%} > {MAX_SE:.2%} at {m.spp} spp (too noisy to decide"
            + ("; more samples did not lower it)" if m.extra.get("floor") else ")")
            for k in range(len(rel)) if m.rel_se[k] > MAX_SE]
    return bad


TIMINGS: list[str] = []


def report(integrator: str, case: str, m: Measured) -> str:
    line = (f"{integrator:>14} x {case:<22} spp {m.spp:5d}  worst {m.rel[np.argmax(np.abs(m.rel))]:+6.2%}  "
            f"se {m.rel_se.max():.2%}  detects {m.detectable:.2%}  {m.seconds:6.2f} s")
    TIMINGS.append(line)
    print(line)
    return line


@pytest.fixture(scope="module", autouse=True)
def print_timings():
    yield
    if TIMINGS:
        print("\nintegrator matrix, per cell:\n" + "\n".join(TIMINGS))


# ------------------------------------------------------------------ tests
def test_every_declared_class_is_one_the_matrix_knows_and_every_integrator_has_a_cell():
    """A class the core does not list would exclude nothing; an integrator with no cell
    would be skipped silently. Also: a radiance integrator is checked on every class some
    scene needs unless it says why not (each exclusion has a reason)."""
    classes = set(_core.PATH_CLASSES)
    assert {p for c in CASES for p in c.paths} <= classes
    assert classes <= {p for c in CASES for p in c.paths}, "a path class no matrix scene covers"
    names = {name for name, _ in cells()}
    for entry in integrators.integrators():
        for x in entry["blind_to"]:
            assert x["paths"] in classes and len(x["reason"]) > 20, (entry["name"], x)
        assert entry["name"] in names, f"{entry['name']} has no cell in the matrix"


@pytest.mark.parametrize("integrator,case", matrix_params())
def test_matrix(integrator, case, tmp_path):
    """One cell: every region within TOLERANCE of its closed form, at a stated power of at
    most 2 %; the same check on the renders as if the light were brighter by that power fails."""
    m = measure(integrator, CASE_BY_NAME[case], tmp_path)
    report(integrator, case, m)
    failures = check(m)
    assert not failures, f"{integrator} on {case}: " + "; ".join(failures)
    assert m.detectable <= 0.02, f"{integrator} on {case}: detects only {m.detectable:.2%}"
    for gain in (1 + m.detectable, 1 - m.detectable):
        assert check(m, gain=gain), f"{integrator} on {case}: the negative control (x{gain:.3f}) passed"


def quick_cells() -> list:
    """One cell per integrator, for the quick tier: its first scene of QUICK_CASES (cheap for
    every integrator: the emitters seen directly, the AO plane)."""
    out, seen = [], set()
    for name, case in cells():
        if name in seen or (name, case) in KNOWN_FAILURES or case not in QUICK_CASES:
            continue
        seen.add(name)
        out.append(pytest.param(name, case, id=f"{name}-{case}"))
    return out


QUICK_CASES = ("emitters_seen", "ao_plane")


@pytest.mark.parametrize("integrator,case", quick_cells())
def test_negative_control_renders_the_brighter_light(integrator, case, tmp_path):
    """The negative control rendered: the scene with its lights brighter by the cell's
    detectable error, with the same seeds, gives the same renders times that gain (so the
    matrix's control on scaled values is the control on the perturbed scene), and the check
    fails on it; the unperturbed scene passes."""
    c = CASE_BY_NAME[case]
    m = measure(integrator, c, tmp_path)
    report(integrator, case, m)
    assert not check(m), check(m)
    assert m.detectable <= 0.02
    gain = 1 + m.detectable
    if c.quantity != "radiance":  # ao has no light to brighten: the albedo does not enter it either
        assert check(m, gain=gain)
        return
    brighter = measure(integrator, c, tmp_path, gain=gain, spp=m.spp)
    np.testing.assert_allclose(brighter.means, m.means * gain, rtol=2e-4)
    brighter.expected = m.expected
    assert check(brighter), f"{integrator} on {case}: a {m.detectable:.2%} brighter light passed"
