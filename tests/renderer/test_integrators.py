"""Integrators against each other and against the determinism guarantee.

`path` and `light` estimate the same image by different means (camera paths with next
event estimation vs. light paths splatted through the camera's importance), so agreement
between them is a test of both against physics, not against yesterday's output.
"""
import numpy as np
import pytest

from tessera_base import integrators
from tessera_renderer import load_scene
from tessera_base.film import resolve_splats
from tessera_renderer.film import new_splat_buffer

import render_cache

W = H = 32
# Family-wise false-alarm rate over the 2 agreement tests x 12 statistics (4 quadrants x 3
# channels), Bonferroni; each statistic gets a Welch t limit for its own degrees of freedom.
FAMILY_ALPHA = 1e-3
COMPARISONS = 2 * 12
POWER = 0.02  # the relative difference every statistic must detect


def render(scene, integrator, seed, spp, **kw):
    """The W x H image; the core's output is cached across runs (tests/render_cache.py)."""
    splatting = integrators.splats(integrator)

    def core_render() -> dict[str, np.ndarray]:
        if splatting:
            splats = new_splat_buffer(W, H)
            cam = scene.render_tile(0, 0, W, H, width=W, height=H, spp=spp, seed=seed, threads=2,
                                    integrator=integrator, splats=splats, **kw)
            return {"img": cam, "splats": splats}
        return {"img": scene.render_tile(0, 0, W, H, width=W, height=H, spp=spp, seed=seed, threads=2, **kw)}

    settings = {"integrator": integrator if splatting else kw.get("integrator"), "seed": seed, "spp": spp,
                "size": [W, H], **kw}
    out = render_cache.cached("integrators", scene, settings, core_render)
    if splatting:
        return resolve_splats(out["img"], out["splats"], W * H * spp, scene.splat_exponent)
    return out["img"]


def quadrant_means(img):
    return np.stack([img[y:y + H // 2, x:x + W // 2, :3].mean(axis=(0, 1))
                     for y in (0, H // 2) for x in (0, W // 2)]).astype(np.float64)


def welch(a_runs, b_runs):
    """Per quadrant and channel, from independent repeats (different seeds): Welch's t of
    mean(a) - mean(b), its Bonferroni limit for the Welch-Satterthwaite degrees of freedom,
    and the smallest relative difference it detects (limit x standard error / mean(b))."""
    from scipy import stats
    a, b = np.array(a_runs), np.array(b_runs)
    va, vb = a.var(axis=0, ddof=1) / len(a), b.var(axis=0, ddof=1) / len(b)
    se = np.sqrt(va + vb)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    limit = stats.t.isf(FAMILY_ALPHA / (2 * COMPARISONS), df)
    return (a.mean(axis=0) - b.mean(axis=0)) / se, limit, limit * se / np.abs(b.mean(axis=0))


@pytest.fixture(scope="module")
def cornell_runs(cornell_path):
    scene = load_scene(cornell_path)
    runs = {name: [quadrant_means(render(scene, name, seed, SPP[name], max_depth=32)) for seed in range(16)]
            for name in ("path", "light", "bdpt")}
    return runs


SPP = {"path": 128, "light": 128, "bdpt": 128}


@pytest.mark.parametrize("integrator", ["light", "bdpt"])
def test_splatting_integrator_converges_to_the_same_cornell_box_as_path(cornell_runs, integrator):
    """Welch t per quadrant and channel. Power: every one of the 12 statistics detects a
    relative difference of 2 % (asserted), and the negative control -- the same statistics
    with this integrator scaled by 2 % away from path -- is flagged on every statistic."""
    t, limit, detectable = welch(cornell_runs[integrator], cornell_runs["path"])
    assert (np.abs(t) < limit).all(), f"{integrator} vs path t:\n{t.round(2)}\nlimits:\n{limit.round(2)}"
    assert (detectable < POWER).all(), f"detectable relative differences:\n{detectable.round(4)}"
    a, b = np.array(cornell_runs[integrator]), np.array(cornell_runs["path"])
    scale = 1 + np.sign(a.mean(axis=0) - b.mean(axis=0)) * POWER
    t2, limit2, _ = welch(a * scale, b)
    assert (np.abs(t2) > limit2).all(), f"{integrator} scaled by 2 % passes:\n{t2.round(2)}"


@pytest.mark.parametrize("integrator", ["light", "bdpt"])
def test_splatting_integrators_are_invariant_to_tiles_threads_and_merge_order(cornell_path, integrator):
    """7 x 5 uneven tiles, each with its own splat buffer, merged in reverse order with one
    thread == the whole image with two threads, bit for bit."""
    scene = load_scene(cornell_path)
    Wi, Hi, spp = 45, 31, 4
    kw = dict(width=Wi, height=Hi, spp=spp, seed=9, max_depth=16, integrator=integrator)
    whole_splats = np.zeros((Hi, Wi, 3), np.int64)
    whole = scene.render_tile(0, 0, Wi, Hi, threads=2, splats=whole_splats, **kw)

    xs, ys = [0, 5, 6, 17, 22, 30, 41, Wi], [0, 3, 11, 12, 26, Hi]
    cam = np.full_like(whole, -1.0)
    tile_splats = []
    for j in range(5):
        for i in range(7):
            x0, y0, w, h = xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]
            buf = np.zeros((Hi, Wi, 3), np.int64)
            cam[y0:y0 + h, x0:x0 + w] = scene.render_tile(x0, y0, w, h, threads=1, splats=buf, **kw)
            tile_splats.append(buf)
    merged = np.zeros_like(whole_splats)
    for buf in reversed(tile_splats):
        merged += buf
    assert cam.tobytes() == whole.tobytes()
    assert np.array_equal(merged, whole_splats)
    assert np.count_nonzero(whole_splats) > 0.5 * whole_splats.size  # splats land all over
    a = resolve_splats(whole, whole_splats, Wi * Hi * spp, scene.splat_exponent)
    b = resolve_splats(cam, merged, Wi * Hi * spp, scene.splat_exponent)
    assert a.tobytes() == b.tobytes()


def test_dropping_out_of_tile_splats_would_be_wrong(cornell_path):
    """A tile's light paths reach pixels far outside it: keeping only in-tile splats (the
    crop-window bug) loses most of the light tracer's image."""
    scene = load_scene(cornell_path)
    buf = new_splat_buffer(W, H)
    scene.render_tile(0, 0, 8, 8, width=W, height=H, spp=16, seed=1, integrator="light", splats=buf)
    inside = buf[:8, :8].sum()
    assert buf.sum() > 5 * inside > 0


def test_unknown_integrator_is_a_clear_error(cornell_path):
    scene = load_scene(cornell_path)
    with pytest.raises(ValueError, match="unknown integrator 'bdtp'"):
        scene.render_tile(0, 0, 4, 4, width=8, height=8, spp=1, integrator="bdtp")
    with pytest.raises(ValueError, match="splat buffer"):
        scene.render_tile(0, 0, 4, 4, width=8, height=8, spp=1, integrator="light")


def test_auto_chooses_bdpt_only_for_caustics_that_path_tracing_cannot_find(tmp_path, cornell_path):
    from pxr import Gf, Sdf, UsdLux, UsdShade

    from usd_fixtures import add_material, add_mesh, new_stage

    assert load_scene(cornell_path).resolve_integrator("auto") == "path"  # diffuse, area light

    def scene_with(point_light=True, **inputs):
        path = tmp_path / f"auto_{len(list(tmp_path.iterdir()))}.usda"
        stage = new_stage(path)
        mat = add_material(stage, "/M", (0.5, 0.5, 0.5))
        shader = UsdShade.Shader(stage.GetPrimAtPath("/M/Surface"))
        for name, value in inputs.items():
            shader.CreateInput(name, Sdf.ValueTypeNames.Float).Set(value)
        add_mesh(stage, "/Q", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [3], [0, 1, 2], mat)
        if point_light:
            bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
            bulb.CreateTreatAsPointAttr(True)
            bulb.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
        else:
            UsdLux.RectLight.Define(stage, "/Panel").AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
        stage.GetRootLayer().Save()
        return load_scene(path)

    assert scene_with(opacity=0.0).resolve_integrator("auto") == "bdpt"                  # glass + bulb
    assert scene_with(metallic=1.0, roughness=0.05).resolve_integrator("auto") == "bdpt"  # mirror + bulb
    assert scene_with(point_light=False, opacity=0.0).resolve_integrator("auto") == "path"  # glass + panel
    assert scene_with(metallic=1.0, roughness=0.8).resolve_integrator("auto") == "path"   # brushed metal
    assert scene_with(roughness=0.05).resolve_integrator("auto") == "path"               # glossy plastic
    assert scene_with(opacity=0.2, opacityThreshold=0.5).resolve_integrator("auto") == "path"  # cutout
    assert scene_with(opacity=0.0).resolve_integrator("whitted") == "whitted"


def test_path_tracing_misses_a_point_light_caustic_that_bdpt_finds(tmp_path):
    """Why `auto` picks bdpt there: a point light above a smooth mirror lights a Lambertian
    ceiling only through the mirror (L S D E). Path tracing cannot sample that path."""
    from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

    from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

    path = tmp_path / "caustic.usda"
    stage = new_stage(path)
    mirror = add_material(stage, "/Mirror", (0.9, 0.9, 0.9))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Mirror/Surface"))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.0)
    add_mesh(stage, "/Floor", [(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)], [4], [0, 1, 2, 3], mirror)
    # A white ceiling facing down at y = 2, and the bulb between: the ceiling's only light
    # comes back from the mirror (a black plate shadows all of it from the bulb).
    ceiling = add_mesh(stage, "/Ceiling", [(-2, 2, -2), (2, 2, -2), (2, 2, 2), (-2, 2, 2)], [4], [0, 1, 2, 3])
    ceiling.CreateDisplayColorAttr([Gf.Vec3f(0.8, 0.8, 0.8)])
    shield = add_mesh(stage, "/Shield", [(-0.5, 1.2, -0.5), (0.5, 1.2, -0.5), (0.5, 1.2, 0.5), (-0.5, 1.2, 0.5)],
                      [4], [0, 1, 2, 3])
    shield.CreateDisplayColorAttr([Gf.Vec3f(0, 0, 0)])
    bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
    bulb.CreateTreatAsPointAttr(True)
    bulb.CreateIntensityAttr(50.0)
    bulb.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
    cam = add_camera(stage, "/Cam", (0, 0.5, 0), focal=20.0)
    UsdGeom.Xformable(cam.GetPrim()).AddRotateXOp().Set(90.0)  # look up at the ceiling
    add_render_settings(stage, cam, (16, 16))
    stage.GetRootLayer().Save()
    scene = load_scene(path)
    assert scene.resolve_integrator("auto") == "bdpt"
    W = H = 16
    path_img = scene.render_tile(0, 0, W, H, width=W, height=H, spp=64, max_depth=8)
    splats = new_splat_buffer(W, H)
    bdpt_img = resolve_splats(scene.render_tile(0, 0, W, H, width=W, height=H, spp=64, max_depth=8,
                                               integrator="bdpt", splats=splats), splats, W * H * 64,
                             scene.splat_exponent)
    assert path_img[..., :3].max() == 0.0          # the caustic does not exist for path tracing
    assert bdpt_img[..., :3].mean() > 0.05         # it does for bdpt


def test_cli_lists_the_registry_with_descriptions():
    """`tessera render --integrator help` prints every registered integrator and its
    one-line description (from the core, not a Python list), then auto."""
    import subprocess
    import sys

    from tessera_renderer import integrators as registry
    out = subprocess.run([sys.executable, "-m", "tessera", "render", "--integrator", "help"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    # One line per integrator; under it, one indented line per setting it declares.
    heads = [line for line in lines if not line.startswith(" ")]
    entries = registry()
    assert len(heads) == len(entries) + 1
    for line, info in zip(heads, entries):
        assert line.split()[0] == info["name"] and line.endswith(info["description"])
        below = lines[lines.index(line) + 1:lines.index(line) + 1 + len(info["params"])]
        for param, setting in zip(info["params"], below):
            assert setting.split()[0] == "--integrator-param" and setting.split()[1].startswith(param + "=")
    assert heads[-1].startswith("auto")
    assert sum(len(i["params"]) for i in entries) == len(lines) - len(heads) > 0
    refused = subprocess.run([sys.executable, "-m", "tessera", "render", "x.usda", "--integrator", "pathh"],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "unknown integrator 'pathh'" in refused.stderr


@pytest.mark.parametrize("integrator", ["light", "bdpt"])
def test_light_path_length_does_not_depend_on_the_light_brightness(cornell_path, integrator):
    """Russian roulette on a light subpath sees its throughput relative to its start. Le / pdf
    is in flux units: rouletting it as is (as camera paths are, from 1) kept every light path
    alive until its absolute throughput fell below 1, so how long light paths were depended
    on the light's units (on this box bdpt cast 3.4 x path's closest rays per sample; now 2 x).
    The rays a render casts must be the same for the box and for the box with its light
    1000 x brighter (every random decision is the same), and the brighter image exactly
    1000 x (to float rounding). The old rule fails the ray count (+1.2 % rays for light,
    +1.6 % for bdpt at 1000 x: light paths that escape the open box end regardless)."""
    from dataclasses import replace

    from tessera_renderer import Scene

    base = load_scene(cornell_path)
    bright = Scene(replace(base.data, emission=base.data.emission * 1000.0))
    counts, images = [], []
    for scene in (base, bright):
        stats = {}
        splats = new_splat_buffer(W, H)
        cam = scene.render_tile(0, 0, W, H, width=W, height=H, spp=8, seed=5, threads=2, integrator=integrator,
                                splats=splats, stats=stats)
        counts.append((stats["closest_rays"], stats["shadow_rays"]))
        images.append(resolve_splats(cam, splats, W * H * 8, scene.splat_exponent)[..., :3].astype(np.float64))
    assert counts[0] == counts[1], f"rays (closest, shadow) for Le and 1000 Le: {counts}"
    np.testing.assert_allclose(images[1], images[0] * 1000.0, rtol=1e-3, atol=1e-6)
