"""AOVs (albedo, normal, depth, spp, variance; docs/aovs.md) against values known without
the renderer, and their merging over passes and tiles."""
import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from tessera_base import images
from tessera.local import render_image
from tessera_base.protocol import RenderSettings, TileRect, TileResult, decode_tile, encode_tile
from tessera_base.convergence import combine_aovs
from tessera_renderer import load_scene
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

ALL = ["albedo", "normal", "depth", "spp", "variance"]
FLOOR = [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)]


def floor_scene(tmp_path, albedo=(0.2, 0.5, 0.8), height=2.0, flip=False):
    """A Lambertian floor (displayColor, no material) at y = 0 seen straight down from
    `height` with a 90-degree field of view, lit by a rect light. `flip` winds it the other
    way."""
    path = tmp_path / f"floor_{flip}.usda"
    stage = new_stage(path)
    order = [3, 2, 1, 0] if flip else [0, 1, 2, 3]
    ground = add_mesh(stage, "/Ground", FLOOR, [4], order)
    ground.CreateDisplayColorAttr([Gf.Vec3f(*albedo)])
    light = UsdLux.RectLight.Define(stage, "/Light")
    light.AddTranslateOp().Set(Gf.Vec3d(3, 4, 0))
    light.AddRotateXOp().Set(-90.0)
    # focal 10, aperture 20: tan(half angle) = 1, a 90-degree view
    cam = add_camera(stage, "/Cam", (0, height, 0), focal=10.0, haperture=20.0, vaperture=20.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (16, 16))
    stage.GetRootLayer().Save()
    return load_scene(path)


@pytest.mark.parametrize("flip", [False, True])
def test_lambertian_floor_albedo_normal_and_depth(tmp_path, flip):
    """Albedo = the Lambertian reflectance exactly (f cos / pdf of cosine sampling is R for
    every sample); normal = +Y, toward the camera, however the floor is wound; depth = the
    camera-space z = the height, at every pixel, although the corner pixels' rays are
    longer (the AOV is z, not distance)."""
    albedo, height = (0.2, 0.5, 0.8), 2.0
    scene = floor_scene(tmp_path, albedo, height, flip)
    rgba, aov = scene.render_tile(0, 0, 16, 16, spp=8, threads=2, aovs=ALL)
    assert (rgba[..., 3] == 1).all()
    np.testing.assert_allclose(aov["albedo"], np.broadcast_to(albedo, (16, 16, 3)), rtol=1e-5)
    np.testing.assert_allclose(aov["normal"], np.broadcast_to((0, 1, 0), (16, 16, 3)), atol=1e-6)
    np.testing.assert_allclose(aov["depth"], height, rtol=1e-5)
    # The corner rays are ~1.7x longer than the height: a distance AOV would fail above.
    corner_ray = height * math.sqrt(1 + (15 / 16) ** 2 * 2)
    assert corner_ray > 1.6 * height
    assert (aov["spp"] == 8).all()
    assert aov["variance"].shape == (16, 16, 3) and aov["variance"].max() > 0  # lit, noisy


def test_albedo_through_a_mirror_is_scaled_by_its_reflectance(tmp_path):
    """A camera looking down at a 45-degree smooth metal plate (reflectance c) sees a
    Lambertian wall of albedo a in it: albedo AOV = c a exactly."""
    c, a = 0.7, np.array([0.3, 0.6, 0.9])
    path = tmp_path / "mirror45.usda"
    stage = new_stage(path)
    mat = add_material(stage, "/Mirror", (c, c, c))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Mirror/Surface"))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.0)
    # plate through the origin with normal (1, 1, 0)/sqrt2: turns rays going -Y into +X
    add_mesh(stage, "/Plate", [(1, -1, -1), (1, -1, 1), (-1, 1, 1), (-1, 1, -1)], [4], [0, 1, 2, 3], mat)
    wall = add_mesh(stage, "/Wall", [(5, -50, -50), (5, 50, -50), (5, 50, 50), (5, -50, 50)], [4], [0, 1, 2, 3])
    wall.CreateDisplayColorAttr([Gf.Vec3f(*a)])
    UsdLux.DomeLight.Define(stage, "/Sky")
    cam = add_camera(stage, "/Cam", (0, 3, 0), focal=100.0, haperture=10.0, vaperture=10.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (8, 8))
    stage.GetRootLayer().Save()
    rgba, aov = load_scene(path).render_tile(0, 0, 8, 8, spp=4, aovs=["albedo", "normal", "depth"])
    np.testing.assert_allclose(aov["albedo"], np.broadcast_to(c * a, (8, 8, 3)), rtol=1e-5)
    np.testing.assert_allclose(aov["normal"], np.broadcast_to(np.array([1, 1, 0]) / math.sqrt(2), (8, 8, 3)),
                               atol=1e-5)
    # Depth of the plate x + y = 0 along a ray (sx, -1) per unit z from (0, 3): z = 3 / (1 - sx)
    # with sx the image-plane coordinate; every sample of pixel column i has sx between its
    # edges, so the pixel's mean depth lies between the depths at the edges.
    edges = (2 * np.arange(9) / 8 - 1) * 0.05
    lo, hi = 3 / (1 - edges[:-1]), 3 / (1 - edges[1:])
    assert ((aov["depth"] >= lo * (1 - 1e-6)) & (aov["depth"] <= hi * (1 + 1e-6))).all(), aov["depth"]


def test_background_is_zero_albedo_and_normal_and_infinite_depth(tmp_path):
    stage = new_stage(tmp_path / "empty.usda")
    add_mesh(stage, "/Far", [(100, 100, 100), (101, 100, 100), (100, 101, 100)], [3], [0, 1, 2])
    UsdLux.DomeLight.Define(stage, "/Sky")
    add_render_settings(stage, add_camera(stage, "/Cam"), (4, 4))
    stage.GetRootLayer().Save()
    rgba, aov = load_scene(tmp_path / "empty.usda").render_tile(0, 0, 4, 4, spp=2, aovs=ALL)
    assert (rgba[..., 3] == 0).all() and rgba[..., :3].min() > 0  # the dome, no geometry
    assert (aov["albedo"] == 0).all() and (aov["normal"] == 0).all()
    assert np.isposinf(aov["depth"]).all()
    assert (aov["spp"] == 2).all()


@pytest.mark.parametrize("integrator", ["path", "bdpt"])
def test_aovs_do_not_change_the_image_and_do_not_depend_on_tiles(cornell_path, integrator):
    scene = load_scene(cornell_path)
    W, H = 24, 18
    kw = dict(width=W, height=H, spp=4, seed=3, max_depth=8, integrator=integrator)

    def render(x0, y0, w, h, **extra):
        splats = np.zeros((H, W, 3), np.int64) if integrator == "bdpt" else None
        return scene.render_tile(x0, y0, w, h, splats=splats, **kw, **extra)

    plain = render(0, 0, W, H, threads=2)
    whole, aov = render(0, 0, W, H, threads=2, aovs=ALL)
    assert plain.tobytes() == whole.tobytes()
    tiled = {name: np.full_like(layer, -1.0) for name, layer in aov.items()}
    for y0, h in ((0, 7), (7, 11)):
        for x0, w in ((0, 10), (10, 14)):
            _, part = render(x0, y0, w, h, threads=1, aovs=ALL)
            for name in tiled:
                tiled[name][y0:y0 + h, x0:x0 + w] = part[name]
    for name in aov:
        assert aov[name].tobytes() == tiled[name].tobytes(), name


def test_passes_merge_to_the_single_render(cornell_path):
    """Samples [0, 3) and [3, 8) combined by convergence.combine_aovs == samples [0, 8):
    albedo and normal as sample-weighted means, spp summed, depth averaged over the hits."""
    scene = load_scene(cornell_path)
    kw = dict(width=40, height=30, seed=3, max_depth=8, aovs=ALL)
    x0, y0, w, h = 0, 0, 40, 30
    whole, aw = scene.render_tile(x0, y0, w, h, spp=8, **kw)
    parts = []
    for p, (start, n) in enumerate([(0, 3), (3, 5)]):
        rgba, a = scene.render_tile(x0, y0, w, h, spp=n, sample_start=start, **kw)
        a.pop("variance")
        parts.append(TileResult(x0, y0, rgba, p, start, n, aovs=a))
    merged = combine_aovs(parts)
    np.testing.assert_allclose(merged["albedo"], aw["albedo"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(merged["normal"], aw["normal"], rtol=1e-5, atol=1e-6)
    assert (merged["spp"][..., 0] == 8).all()
    finite = np.isfinite(aw["depth"])
    assert (~finite).any() and finite.any()  # the Cornell box's open front: some background
    np.testing.assert_array_equal(np.isfinite(merged["depth"][..., 0]), finite)
    np.testing.assert_allclose(merged["depth"][..., 0][finite], aw["depth"][finite], rtol=1e-5)


def test_tile_results_carry_aovs(cornell_path):
    """Result format version 3 carries AOVs; a result without them stays version 2."""
    rect = TileRect(index=0, x0=2, y0=1, width=5, height=3)
    rng = np.random.default_rng(1)
    rgba = rng.random((3, 5, 4), dtype=np.float32)
    aovs = {"albedo": rng.random((3, 5, 3), dtype=np.float32), "depth": rng.random((3, 5), dtype=np.float32),
            "spp": np.full((3, 5), 4, np.float32)}
    data = encode_tile(rect, rgba, spp=4, aovs=aovs, variance=rng.random((3, 5, 3), dtype=np.float32))
    assert int.from_bytes(data[4:8], "little") == 3
    r = decode_tile(data)
    assert set(r.aovs) == {"albedo", "depth", "spp"}
    assert np.array_equal(r.aovs["albedo"], aovs["albedo"])
    assert np.array_equal(r.aovs["depth"][..., 0], aovs["depth"])
    assert np.array_equal(r.rgba, rgba)
    assert int.from_bytes(encode_tile(rect, rgba, spp=4)[4:8], "little") == 2
    with pytest.raises(ValueError, match="bytes"):
        decode_tile(data[:-4])
    with pytest.raises(ValueError, match="AOV normal"):
        encode_tile(rect, rgba, aovs={"normal": aovs["albedo"][:2]})
    # A version-2 result claiming the AOV flag is refused, not misread.
    bad = data[:4] + (2).to_bytes(4, "little") + data[8:]
    with pytest.raises(ValueError, match="unknown flags"):
        decode_tile(bad)


def test_local_render_writes_aov_layers_and_noise_target_spp(tmp_path, cornell_path):
    """`tessera render --aovs all` in noise-target mode: spp is the per-tile sample count
    the pass schedule reached, and every layer is in the EXR under its OpenEXR name."""
    from tessera_cli.cli import main

    out = tmp_path / "c.exr"
    assert main(["render", str(cornell_path), "--res", "32x24", "--tile", "8", "--target-error", "0.2",
                 "--min-spp", "2", "--max-spp", "16", "--aovs", "all", "-q", "-o", str(out)]) == 0
    channels = images.read_exr_channels(out)
    for name in ("R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z", "Z", "spp",
                 "variance.R", "variance.G", "variance.B"):
        assert name in channels, name
    spp = channels["spp"]
    assert set(np.unique(spp)) <= {2.0, 4.0, 8.0, 16.0} and len(np.unique(spp)) > 1
    for y0 in range(0, 24, 8):  # constant within each tile
        for x0 in range(0, 32, 8):
            assert np.unique(spp[y0:y0 + 8, x0:x0 + 8]).size == 1
    settings = RenderSettings(width=32, height=24, tile_size=8, target_error=0.2, min_spp=2, max_spp=16,
                              aovs="all")
    local = render_image(load_scene(cornell_path), settings, progress=False)
    for name, layer in images.read_exr_aovs(out).items():
        assert layer.tobytes() == local.aovs[name].tobytes(), name


def test_unknown_aov_is_a_clear_error(cornell_path):
    scene = load_scene(cornell_path)
    with pytest.raises(ValueError, match="unknown AOV 'albdeo'"):
        scene.render_tile(0, 0, 2, 2, width=4, height=4, spp=1, aovs=["albdeo"])
    with pytest.raises(ValueError, match="unknown AOV 'nrm'"):
        RenderSettings(width=4, height=4, aovs="albedo,nrm")
    assert RenderSettings(width=4, height=4, aovs="depth, albedo,depth").aovs == ["albedo", "depth"]


def test_normal_is_the_authored_shading_normal(tmp_path):
    """With authored normals (tilted, constant) the N layer is the shading normal, not the
    facet's: the floor is flat, its normals lean 30 degrees toward +X."""
    path = tmp_path / "tilted.usda"
    stage = new_stage(path)
    ground = add_mesh(stage, "/Ground", FLOOR, [4], [0, 1, 2, 3])
    ground.CreateDisplayColorAttr([Gf.Vec3f(0.5, 0.5, 0.5)])
    n = (math.sin(math.radians(30)), math.cos(math.radians(30)), 0.0)
    ground.CreateNormalsAttr([Gf.Vec3f(*n)] * 4)
    ground.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    UsdLux.DomeLight.Define(stage, "/Sky")
    cam = add_camera(stage, "/Cam", (0, 2, 0), focal=10.0, haperture=20.0, vaperture=20.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (8, 8))
    stage.GetRootLayer().Save()
    _, aov = load_scene(path).render_tile(0, 0, 8, 8, spp=2, aovs=["normal"])
    np.testing.assert_allclose(aov["normal"], np.broadcast_to(n, (8, 8, 3)), atol=1e-5)


def test_albedo_through_glass_is_the_transmittance(tmp_path):
    """A Lambertian floor (albedo a) under a smooth glass pane (ior 1.5), seen straight down:
    each sample refracts (probability 1 - F, albedo a: the radiance scaling 1/eta^2 is left
    out) or reflects into the empty sky (probability F, albedo 0), F = ((n-1)/(n+1))^2 =
    0.04 at normal incidence. The mean is (1 - F) a, within the binomial noise."""
    a, n = 0.6, 1.5
    path = tmp_path / "pane.usda"
    stage = new_stage(path)
    ground = add_mesh(stage, "/Ground", FLOOR, [4], [0, 1, 2, 3])
    ground.CreateDisplayColorAttr([Gf.Vec3f(a, a, a)])
    mat = add_material(stage, "/Glass", (0.0, 0.0, 0.0))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Glass/Surface"))
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.0)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.0)
    shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(n)
    add_mesh(stage, "/Pane", [(-5, 1, -5), (-5, 1, 5), (5, 1, 5), (5, 1, -5)], [4], [0, 1, 2, 3], mat)
    UsdLux.DomeLight.Define(stage, "/Sky")
    cam = add_camera(stage, "/Cam", (0, 3, 0), focal=100.0, haperture=10.0, vaperture=10.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (8, 8))
    stage.GetRootLayer().Save()
    spp = 64
    _, aov = load_scene(path).render_tile(0, 0, 8, 8, spp=spp, aovs=["albedo"], sampler="independent")
    F = ((n - 1) / (n + 1)) ** 2  # within 1e-4 of the Fresnel term over this 6-degree view
    samples = 64 * spp
    se = a * math.sqrt(F * (1 - F) / samples)
    mean = float(aov["albedo"].mean())
    assert abs(mean - (1 - F) * a) < 5 * se + 1e-4 * a, (mean, (1 - F) * a, se)
    # With the radiance scaling left in, the mean would be (1 - F) a / n^2: far outside.
    assert abs(mean - (1 - F) * a / n ** 2) > 100 * se
