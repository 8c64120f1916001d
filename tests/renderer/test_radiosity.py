"""Radiosity and the hybrid against path tracing on the Cornell box (examples/cornell).

The box's UsdPreviewSurface walls have a rough specular lobe whose Fresnel term brightens
grazing views: no view-independent method can reproduce that, so the comparisons use the
same box made Lambertian (the same diffuse colours, material_params dropped), where
radiosity's model is exact and only meshing and the solver's tolerance separate it from
the path tracer.

Precision: the path reference has 1024 samples per pixel; each wall region holds 70 to 240
pixels, so its mean has a relative standard error of about 0.3 %. The radiosity check
allows 2 % per region (the issue's bound), so it detects a 2 % error once the meshing bias
is below ~1.5 %; the negative control scales the solution by 1.03 (transport is linear,
so that is the image of a light 3 % brighter) and requires the same check to fail.
"""
from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest

from conftest import CORNELL
from tessera.preview import RadiosityPreview
from tessera_renderer import Scene, load_scene

W = 64
LUM = np.array([0.2126, 0.7152, 0.0722])
# Pixel rows and columns (64 x 64) of each wall, clear of the blocks, the light and the edges
# (the ceiling starts two rows below its open front edge, where radiosity changes fastest).
REGIONS = {"back": (8, 18, 22, 42), "left": (16, 40, 2, 9), "right": (16, 40, 55, 62),
           "ceiling": (3, 8, 8, 22), "floor": (58, 63, 4, 20)}
FINE, COARSE = 50.0, 100.0  # element sizes (the box is 555 units wide)


def _still_solution_header(product: bytes) -> tuple:
    """The solution header of a still scene's radiosity product (radiosity_product.cpp): an
    outer header naming one time slice, then the slice's (tag, elements, vertices, shots or
    links, relative residual, converged)."""
    magic, slices = struct.unpack("4sI", product[:8])
    assert magic == b"TRA3" and slices == 1, (magic, slices)
    return struct.unpack("4sIIIfI", product[8:32])


@pytest.fixture(scope="module")
def cornell() -> Scene:
    data = load_scene(str(CORNELL)).data
    return Scene(dataclasses.replace(data, material_params=None))


@pytest.fixture(scope="module")
def path_reference(cornell) -> np.ndarray:
    return cornell.render_tile(0, 0, W, W, width=W, height=W, spp=1024, threads=2, integrator="path", seed=1)


def region_means(img: np.ndarray) -> dict[str, float]:
    return {k: float((img[r0:r1, c0:c1, :3] @ LUM).mean()) for k, (r0, r1, c0, c1) in REGIONS.items()}


def relative_errors(img: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    a, b = region_means(img), region_means(ref)
    return {k: a[k] / b[k] - 1 for k in a}


def render(scene: Scene, integrator: str, params: dict, spp: int, product: bytes | None = None) -> np.ndarray:
    product = product or scene.scene_pass(integrator, 0, threads=2, integrator_params=params)
    return scene.render_tile(0, 0, W, W, width=W, height=W, spp=spp, threads=2, integrator=integrator,
                             integrator_params=params, scene_product=product, seed=2)


@pytest.mark.slow
def test_radiosity_matches_path_per_wall_and_meshing_bias_shrinks(cornell, path_reference):
    fine = relative_errors(render(cornell, "radiosity", {"element_size": FINE, "refine_levels": 0}, 4), path_reference)
    coarse = relative_errors(render(cornell, "radiosity", {"element_size": COARSE, "refine_levels": 0}, 4),
                             path_reference)
    print("fine", fine, "coarse", coarse)
    assert max(abs(e) for e in fine.values()) < 0.02, fine
    # Meshing bias shrinks under refinement: in the worst region and on average.
    assert max(abs(e) for e in fine.values()) < max(abs(e) for e in coarse.values())
    assert sum(abs(e) for e in fine.values()) < sum(abs(e) for e in coarse.values())
    # Negative control: a solution 3 % too bright fails the same check.
    brighter = {k: (1 + e) * 1.03 - 1 for k, e in fine.items()}
    assert max(abs(e) for e in brighter.values()) >= 0.02, brighter


@pytest.mark.slow
def test_default_radiosity_matches_path_per_wall_without_choosing_an_element_size(cornell, path_reference):
    """The default (no setting given: the direct light evaluated at the vertices, the mesh
    refined where its interpolation misses, at most 8192 elements, shot by rays): every wall
    region within 2 % of `path` (measured -0.5 % to +1.1 %, where the default before was off
    by up to 3.3 % on the right wall and 2.9 % on the floor: docs/benchmarks/radiosity-default.md).
    The same solution 3 % brighter must fail."""
    product = cornell.scene_pass("radiosity", 0, threads=2, integrator_params={})
    _, elements, _, _, _, _ = _still_solution_header(product)
    errors = relative_errors(render(cornell, "radiosity", {}, 4, product), path_reference)
    print("default", errors, f"{elements} elements")
    assert max(abs(e) for e in errors.values()) < 0.02, errors
    brighter = {k: (1 + e) * 1.03 - 1 for k, e in errors.items()}
    assert max(abs(e) for e in brighter.values()) >= 0.02, brighter


@pytest.mark.slow
def test_hierarchical_agrees_with_progressive_within_one_percent_with_far_fewer_links(cornell):
    """Both solves are deterministic and both images are rendered from the same camera
    samples, so the per-region ratio carries no noise: the 1 % bound (the issue's) is the
    whole tolerance. Measured at element size 50 (3404 elements): -0.8 % to +0.4 % per
    region with 1.15 M links, a tenth of the 11.6 M element pairs. The negative control, the
    hierarchical solution 2 % brighter, must fail the same check."""
    params = {"element_size": FINE, "refine_levels": 0}
    progressive = cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params)
    hierarchical = cornell.scene_pass("radiosity", 0, threads=2, integrator_params={**params, "solver": 1})
    _, elements, _, _, _, _ = _still_solution_header(progressive)
    _, _, _, links, _, converged = _still_solution_header(hierarchical)
    errors = relative_errors(render(cornell, "radiosity", params, 4, hierarchical),
                             render(cornell, "radiosity", params, 4, progressive))
    print("hierarchical vs progressive", errors, f"{links} links for {elements} elements")
    assert converged
    assert max(abs(e) for e in errors.values()) < 0.01, errors
    assert links * 5 < elements ** 2, (links, elements)
    brighter = {k: (1 + e) * 1.02 - 1 for k, e in errors.items()}
    assert max(abs(e) for e in brighter.values()) >= 0.01, brighter


@pytest.mark.slow
def test_stochastic_solver_matches_path_per_wall(cornell, path_reference):
    """The stochastic solver (solver 2: shooting by ray casting, no form factors) carries
    the same meshing bias as the progressive one and its own noise (1024 rays per element:
    about 0.2 % per region). Measured at element size 50: -0.6 % to +0.7 % per region, as
    the progressive solver's -0.6 % to +0.7 %, with a seventh of its solve time (1.2 s
    against 8.3 s). The negative control: the same solution 3 % brighter fails."""
    params = {"element_size": FINE, "solver": 2, "refine_levels": 0}
    product = cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params)
    _, elements, _, iterations, residual, converged = _still_solution_header(product)
    assert converged and residual < 1e-3 and iterations > 1, (iterations, residual)
    errors = relative_errors(render(cornell, "radiosity", params, 4, product), path_reference)
    print("stochastic", errors, f"{iterations} iterations over {elements} elements")
    assert max(abs(e) for e in errors.values()) < 0.02, errors
    brighter = {k: (1 + e) * 1.03 - 1 for k, e in errors.items()}
    assert max(abs(e) for e in brighter.values()) >= 0.02, brighter


def test_default_solver_is_progressive_for_small_meshes_and_stochastic_for_large(cornell):
    """Above 4096 elements the default is the stochastic solver (the progressive one's
    form factors cost O(n^2)): the default's product is the explicit solver's bytes (on an
    unrefined mesh; the default's refined mesh is always shot by rays)."""
    small = {"element_size": 100.0, "refine_levels": 0}  # 884 elements
    assert cornell.scene_pass("radiosity", 0, threads=2, integrator_params=small) == \
        cornell.scene_pass("radiosity", 0, threads=2, integrator_params={**small, "solver": 0})
    large = {"element_size": 40.0, "rays_per_element": 16, "refine_levels": 0}
    product = cornell.scene_pass("radiosity", 0, threads=2, integrator_params=large)
    assert _still_solution_header(product)[1] > 4096
    assert product == cornell.scene_pass("radiosity", 0, threads=2, integrator_params={**large, "solver": 2})
    assert product != cornell.scene_pass("radiosity", 0, threads=2, integrator_params={**large, "solver": 0,
                                                                                      "tolerance": 0.5})


def test_stochastic_solution_is_the_same_for_any_thread_count(cornell):
    params = {"element_size": 150.0, "solver": 2, "rays_per_element": 64}
    one = cornell.scene_pass("radiosity", 0, threads=1, integrator_params=params)
    assert cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params) == one
    assert cornell.scene_pass("radiosity", 0, threads=2, integrator_params={**params, "rays_per_element": 65}) != one


def test_refined_solution_travels_in_the_product(cornell):
    """Adaptive refinement's mesh is named in the product (each element's quadtree depth),
    so a tile rebuilds it from the bytes alone; the same settings give the same bytes on
    any thread count, and a product cut inside its depths is refused."""
    params = {"element_size": 150.0, "solver": 2, "rays_per_element": 64, "refine_levels": 2}
    product = cornell.scene_pass("radiosity", 0, threads=1, integrator_params=params)
    assert cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params) == product
    _, elements, _, _, _, _, cells, depth_bytes = struct.unpack("4sIIIfIII", product[8:40])
    assert elements > cells and depth_bytes == elements, (elements, cells, depth_bytes)
    refined = render(cornell, "radiosity", params, 1, product)
    uniform = render(cornell, "radiosity", {**params, "refine_levels": 0}, 1)
    assert np.abs(refined - uniform).max() > 0  # the refined mesh is what is shown
    with pytest.raises(ValueError, match="truncated"):
        render(cornell, "radiosity", params, 1, product[:40 + depth_bytes // 2])


@pytest.mark.slow
def test_hybrid_matches_path_and_counts_direct_light_once(cornell, path_reference):
    """The hybrid's noise per region is about 0.5 % at 256 spp and its gather reads the
    coarse solution one bounce away, where the meshing bias is diluted by the bounce: the
    check allows 2 %. Counting direct light twice (NEE plus the solution's direct part at
    the first vertex) would add the direct image once more, `local` minus nothing (no
    region sees an emitter): the same check must refuse that."""
    params = {"element_size": COARSE, "refine_levels": 0}
    hybrid = render(cornell, "hybrid", params, 256)
    errors = relative_errors(hybrid, path_reference)
    print("hybrid", errors)
    assert max(abs(e) for e in errors.values()) < 0.02, errors
    direct = cornell.render_tile(0, 0, W, W, width=W, height=W, spp=256, threads=2, integrator="local", seed=3)
    twice = relative_errors(hybrid + direct, path_reference)
    assert max(abs(e) for e in twice.values()) >= 0.02, twice


def _cornell_with_mirror_and_glass(folder) -> Scene:
    """The Cornell box with a smooth mirror on the left of its back wall and a clear glass
    sphere on its floor (UsdPreviewSurface: metallic 1 roughness 0; opacity 0, ior 1.5), the
    walls made Lambertian (their preview_surface flag cleared, the mirror's and the glass's
    kept)."""
    import shutil
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade
    shutil.copy(CORNELL, folder / "cornell.usda")
    stage = Usd.Stage.CreateNew(str(folder / "room.usda"))
    stage.GetRootLayer().subLayerPaths.append("cornell.usda")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)

    def material(name, **inputs):
        m = UsdShade.Material.Define(stage, f"/Extra/Looks/{name}")
        shader = UsdShade.Shader.Define(stage, f"/Extra/Looks/{name}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        for k, v in inputs.items():
            if isinstance(v, tuple):
                shader.CreateInput(k, Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*v))
            else:
                shader.CreateInput(k, Sdf.ValueTypeNames.Float).Set(v)
        m.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        return m

    quad = UsdGeom.Mesh.Define(stage, "/Extra/mirror")
    quad.CreatePointsAttr([Gf.Vec3f(*p) for p in [(540, 120, 555), (360, 120, 555), (360, 400, 555), (540, 400, 555)]])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    UsdShade.MaterialBindingAPI.Apply(quad.GetPrim()).Bind(
        material("mirror", diffuseColor=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0))
    sphere = UsdGeom.Sphere.Define(stage, "/Extra/glass")
    sphere.CreateRadiusAttr(80.0)
    sphere.AddTranslateOp().Set(Gf.Vec3d(420, 80, 150))
    UsdShade.MaterialBindingAPI.Apply(sphere.GetPrim()).Bind(material("glass", opacity=0.0, ior=1.5, roughness=0.0))
    stage.GetRootLayer().Save()
    data = load_scene(str(folder / "room.usda")).data
    params = dict(data.material_params)
    lambertian = (params["metallic"] == 0) & (params["opacity"] == 1)
    params["preview_surface"] = np.where(lambertian, 0.0, params["preview_surface"]).astype(np.float32)
    return Scene(dataclasses.replace(data, material_params=params))


@pytest.mark.slow
def test_hybrid_matches_path_with_a_mirror_and_a_glass_sphere(tmp_path):
    """Light a mirror or glass throws onto the walls (L S D ... E) is in the solution only if
    the solve carries it: the stochastic solver's rays go on across delta surfaces
    (Wallace's extended form factors, sampled), and it is the default solver for such a
    scene. Regions: the walls, ceiling and floor (2 %), the view in the mirror (2 %) and
    through the glass sphere (3 %: it holds the caustic, seen through the glass, whose
    heavy-tailed estimates converge slowest). Measured (hybrid 1024 spp against path
    2 x 1024, element size 50): -1.2 % (the mirror) to +0.3 %, -0.7 % through the glass.
    The control is the progressive solver, whose form factors stop at the mirror and the
    glass: without that light the ceiling is 13 % too dark and the view through the glass
    30 %, which must fail; so must the stochastic solution 3 % brighter."""
    scene = _cornell_with_mirror_and_glass(tmp_path)
    regions = {**REGIONS, "floor": (58, 63, 44, 60), "mirror": (26, 36, 15, 18), "glass": (46, 56, 12, 22)}
    bound = {k: 0.03 if k == "glass" else 0.02 for k in regions}

    def means(img):
        return {k: float((img[r0:r1, c0:c1, :3] @ LUM).mean()) for k, (r0, r1, c0, c1) in regions.items()}

    ref = means(sum(scene.render_tile(0, 0, W, W, width=W, height=W, spp=1024, threads=2, integrator="path", seed=s)
                    for s in (1, 2)) / 2)

    def errors(solver):
        params = {"element_size": FINE, "refine_levels": 0, **({"solver": solver} if solver is not None else {})}
        product = scene.scene_pass("hybrid", 0, threads=2, integrator_params=params)
        img = scene.render_tile(0, 0, W, W, width=W, height=W, spp=1024, threads=2, integrator="hybrid",
                                integrator_params=params, scene_product=product, seed=5)
        got = means(img)
        return {k: got[k] / ref[k] - 1 for k in regions}

    default = errors(None)
    assert default == errors(2)  # the default for a scene with delta surfaces is the stochastic solver
    print("hybrid with mirror and glass", default)
    assert all(abs(default[k]) < bound[k] for k in regions), default
    progressive = errors(0)
    print("progressive solver", progressive)
    assert not all(abs(progressive[k]) < bound[k] for k in regions), progressive
    brighter = {k: (1 + e) * 1.03 - 1 for k, e in default.items()}
    assert not all(abs(brighter[k]) < bound[k] for k in regions), brighter


def test_solution_is_one_product_per_scene_and_settings(cornell):
    params = {"element_size": 120.0}
    first = cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params)
    assert cornell.scene_pass("radiosity", 3, threads=1, integrator_params=params) == first
    assert cornell.scene_pass("hybrid", 0, threads=2, integrator_params=params) == first
    assert cornell.scene_pass("radiosity", 0, threads=2, integrator_params={"element_size": 150.0}) != first


def test_bad_settings_and_foreign_products_are_refused(cornell):
    with pytest.raises(ValueError, match="element_size must be a finite number > 0"):
        cornell.scene_pass("radiosity", 0, integrator_params={"element_size": 0})
    with pytest.raises(ValueError, match="elements .at most 4194304.; make it larger"):
        cornell.scene_pass("radiosity", 0, integrator_params={"element_size": 1e-3})
    with pytest.raises(ValueError, match="tolerance"):
        cornell.scene_pass("radiosity", 0, integrator_params={"tolerance": 2})
    with pytest.raises(ValueError, match=r"solver must be 0 \(progressive\), 1 \(hierarchical\) or 2 \(stochastic\)"):
        cornell.scene_pass("radiosity", 0, integrator_params={"solver": 3})
    with pytest.raises(ValueError, match="rays_per_element must be a number from 1 to 1e6"):
        cornell.scene_pass("radiosity", 0, integrator_params={"solver": 2, "rays_per_element": 0})
    with pytest.raises(ValueError, match="refine_levels must be a whole number from 0 to 3"):
        cornell.scene_pass("radiosity", 0, integrator_params={"refine_levels": 4})
    with pytest.raises(ValueError, match="refine_levels needs solver 0 .progressive. or 2 .stochastic."):
        cornell.scene_pass("radiosity", 0, integrator_params={"refine_levels": 1, "solver": 1})
    product = cornell.scene_pass("radiosity", 0, threads=2, integrator_params={"element_size": 150.0})
    with pytest.raises(ValueError, match="another scene or element_size"):
        render(cornell, "radiosity", {"element_size": 120.0}, 1, product=product)
    photons = cornell.scene_pass("photon_direct", 0, integrator_params={"photons": 100})
    with pytest.raises(ValueError, match="not a radiosity solution"):
        render(cornell, "radiosity", {"element_size": 150.0}, 1, product=photons)


def test_preview_frames_are_the_radiosity_image_from_a_moved_camera():
    scene = load_scene(str(CORNELL))
    params = {"element_size": 150.0}
    preview = RadiosityPreview(scene, width=48, height=48, threads=2, integrator_params=params)
    still = scene.render_tile(0, 0, 48, 48, width=48, height=48, spp=1, threads=2, integrator="radiosity",
                              integrator_params=params, scene_product=preview.product)
    assert np.array_equal(preview.frame(), still)
    turned = preview.frame(yaw=math.radians(20))
    assert not np.array_equal(turned, still)
    # Orbiting left and right by the same angle mirrors the view of the box's symmetric
    # shell; the blocks are not symmetric, so only the frame's mean brightness is compared.
    other = preview.frame(yaw=-math.radians(20))
    assert abs(float(turned[..., 3].mean()) - float(other[..., 3].mean())) < 0.05


def test_a_degenerate_triangle_gets_one_element_however_long(cornell):
    """A zero-area triangle (a line 1e30 long, as a fuzzer wrote it) exchanges no light: it
    is one element, not 4096^2 that refuse the solve. The Cornell box with such a sliver
    added solves to the same elements plus one."""
    data = cornell.data
    far = np.array([[0.0, 1e30, 1e30], [1e30, 1e30, 1e30]], np.float32)
    base = len(data.positions)
    sliver = dataclasses.replace(
        data, positions=np.vstack([data.positions.reshape(-1, 3), far]),
        indices=np.vstack([data.indices.reshape(-1, 3), [[base, base + 1, base + 1]]]).astype(np.uint32),
        triangle_material=np.concatenate([data.triangle_material, data.triangle_material[:1]]),
        shading_normals=None if data.shading_normals is None else
        np.concatenate([data.shading_normals, data.shading_normals[:1]]),
        uvs=None)
    params = {"element_size": COARSE, "refine_levels": 0}
    plain = cornell.scene_pass("radiosity", 0, threads=2, integrator_params=params)
    with_sliver = Scene(sliver).scene_pass("radiosity", 0, threads=2, integrator_params=params)
    elements = [_still_solution_header(p)[1] for p in (plain, with_sliver)]
    assert elements[1] == elements[0] + 1, elements


# --- A lit plane, point by point (issue 46) --------------------------------------------------
#
# A 4 x 4 Lambertian floor (albedo 0.5) under one light 1 unit above its centre, nothing else:
# the floor's radiance is rho L F (rho/pi times the irradiance pi L F) with F the point-to-
# light form factor, known in closed form: Lambert's contour integral for a polygon (a
# RectLight, and an emissive hexagon mesh, the "area mesh light"), pi L R^2 cos / D^2 for a
# sphere wholly above the plane. The floor sees nothing else (the lights reflect nothing),
# so no interreflection enters. The radiosity is read at single points by a 1 x 1
# orthographic camera with a window 2e-4 wide: the centre under the light, points off its
# axis, near an edge and near a corner, where a lit plane's display was 9 % under and up to
# 45 % over (the default mesh, element means interpolated). Only the defaults are used:
# no element size is chosen. The check is 2 % at every point (deterministic: the solution
# and the point's value carry no noise between runs); the negative control, the closed
# form of a light 2.5 % brighter, must fail it.

PLANE_HALF, LIGHT_HEIGHT, PLANE_RHO = 2.0, 1.0, 0.5
PLANE_POINTS = [(0.0, 0.0), (0.37, -0.21), (0.8, 0.55), (1.9, 0.1), (-1.93, -1.9), (1.3, -1.7)]


def _lambert_polygon_factor(x, n, polygon) -> float:
    """Point-to-polygon form factor, (1/2pi) |sum_i gamma_i n . unit(R_i x R_i+1)|, for a
    polygon wholly above the point's plane (Cohen & Wallace eq. 4.19)."""
    r = [np.asarray(p, float) - x for p in polygon]
    total = 0.0
    for a, b in zip(r, r[1:] + r[:1]):
        c = np.cross(a, b)
        total += math.atan2(np.linalg.norm(c), float(np.dot(a, b))) * float(np.dot(c / np.linalg.norm(c), n))
    return abs(total) / (2 * math.pi)


def _lit_plane(folder, light: str):
    """The scene file and the closed-form radiance of the floor at (x, z)."""
    from pxr import Gf, Sdf, UsdLux, UsdShade
    from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, emission_only, new_stage

    path = folder / f"plane_{light}.usda"
    stage = new_stage(path)
    h = PLANE_HALF
    ground = add_mesh(stage, "/Floor", [(-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h)], [4], [0, 1, 2, 3])
    ground.CreateDisplayColorAttr([Gf.Vec3f(PLANE_RHO, PLANE_RHO, PLANE_RHO)])
    up = np.array([0.0, 1.0, 0.0])
    if light == "rect":
        L, w, d = 3.0, 1.0, 1.0
        rect = UsdLux.RectLight.Define(stage, "/Light")
        rect.AddTranslateOp().Set(Gf.Vec3d(0, LIGHT_HEIGHT, 0))
        rect.AddRotateXOp().Set(-90.0)  # its emitting -Z to world -Y
        rect.CreateWidthAttr(w)
        rect.CreateHeightAttr(d)
        rect.CreateIntensityAttr(L)
        polygon = [(-w / 2, LIGHT_HEIGHT, -d / 2), (w / 2, LIGHT_HEIGHT, -d / 2), (w / 2, LIGHT_HEIGHT, d / 2),
                   (-w / 2, LIGHT_HEIGHT, d / 2)]
    elif light == "mesh":
        L, r = 2.0, 0.6
        emission_only(stage)
        lamp = add_material(stage, "/Lamp", (0.0, 0.0, 0.0), (L, L, L))
        # No specular lobe either: the lamp reflects nothing back onto the floor.
        shader = UsdShade.Shader(stage.GetPrimAtPath("/Lamp/Surface"))
        shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
        polygon = [(r * math.cos(math.pi * k / 3), LIGHT_HEIGHT, r * math.sin(math.pi * k / 3)) for k in range(6)]
        add_mesh(stage, "/Hexagon", polygon, [6], list(range(6)), lamp)  # wound to face down
    else:
        L, R = 4.0, 0.2
        sphere = UsdLux.SphereLight.Define(stage, "/Light")
        sphere.AddTranslateOp().Set(Gf.Vec3d(0, LIGHT_HEIGHT, 0))
        sphere.CreateRadiusAttr(R)
        sphere.CreateIntensityAttr(L)
    cam = add_camera(stage, "/Cam", (0, 0.5, 0), focal=20.0)
    cam.AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (8, 8))
    stage.GetRootLayer().Save()

    def radiance(x: float, z: float) -> float:
        if light == "sphere":
            d2 = x * x + z * z + LIGHT_HEIGHT ** 2
            return PLANE_RHO / math.pi * math.pi * L * R * R * (LIGHT_HEIGHT / math.sqrt(d2)) / d2
        return PLANE_RHO * L * _lambert_polygon_factor(np.array([x, 0.0, z]), up, polygon)

    return path, radiance


def _radiosity_at_points(scene: Scene, points, params: dict) -> list[float]:
    """The radiosity image at floor points (x, z), each through its own 1-pixel orthographic
    camera looking straight down (scene coordinates are the world's less world_offset)."""
    from tessera_renderer import _core

    product = scene.scene_pass("radiosity", 0, threads=2, integrator_params=params)
    offset = np.asarray(scene.data.world_offset, float)
    values = []
    for x, z in points:
        origin = np.array([x, 0.5, z]) - offset
        cam = _core.Camera(tuple(origin), (1, 0, 0), (0, 0, 1), (0, -1, 0), 1e-4, 1e-4, 1, 1, orthographic=True)
        img = scene.render_tile(0, 0, 1, 1, width=1, height=1, spp=1, threads=2, integrator="radiosity",
                                integrator_params=params, scene_product=product, camera=cam)
        values.append(float(img[0, 0, :3].mean()))
    return values


@pytest.mark.parametrize("light", ["rect", "mesh", "sphere"])
def test_default_radiosity_of_a_lit_plane_is_within_two_percent_at_every_point(tmp_path, light):
    path, radiance = _lit_plane(tmp_path, light)
    values = _radiosity_at_points(load_scene(path), PLANE_POINTS, {})
    expected = [radiance(x, z) for x, z in PLANE_POINTS]
    errors = [v / e - 1 for v, e in zip(values, expected)]
    print(light, " ".join(f"{100 * e:+.2f}%" for e in errors))

    def within(reference):
        return all(abs(v / r - 1) < 0.02 for v, r in zip(values, reference))

    assert within(expected), errors
    assert not within([1.025 * e for e in expected])


def test_default_refined_solution_is_the_same_bytes_for_any_thread_count(tmp_path):
    """The farm stores one solution per scene and settings: the default's point evaluations,
    its refinement (largest misses first, ties by index) and its ray-shot solve must give
    the same bytes on 1 and 2 threads, under a sphere light (NEE at the points) and a rect
    light (form factors); the mesh is refined (more elements than uniform cells)."""
    for light in ("sphere", "rect"):
        scene = load_scene(_lit_plane(tmp_path, light)[0])
        one = scene.scene_pass("radiosity", 0, threads=1, integrator_params={})
        assert scene.scene_pass("radiosity", 0, threads=2, integrator_params={}) == one
        _, elements, _, _, _, _, cells, depth_bytes = struct.unpack("4sIIIfIII", one[8:40])
        assert elements > cells and depth_bytes == elements, (elements, cells)
