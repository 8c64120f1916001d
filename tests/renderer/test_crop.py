"""A crop renders only the tiles that meet it, cut to it (protocol.job_tiles), and its
pixels equal the full render's region bit for bit: for path (tile passes), sppm and
radiosity (a scene-wide pass before the tiles), and for the splatting integrators (light,
bdpt, vcm), whose crop pixels gather light paths started from every pixel: they trace
every pixel's light paths but, outside the crop (the camera window), bdpt and vcm skip the
camera subpaths and every strategy but the splats, whose sampler values must stay the full
render's (a pinhole ignores the lens sample the splats draw after the camera subpath; a
thin lens does not, so there the subpath is still traced: both cameras are tested).
The time this saves is measured in benchmarks/crop.py (docs/benchmarks/crop.md)."""
from __future__ import annotations

import numpy as np
import pytest

import tessera
from conftest import CORNELL
from tessera_base import integrators
from tessera_base.protocol import RenderSettings, job_tiles

RES = (64, 48)
CROP = (20, 12, 52, 44)  # not on the 16 px tile grid: edge tiles are cut
X0, Y0, X1, Y1 = CROP


def test_job_tiles_are_the_grid_tiles_meeting_the_crop_cut_to_it():
    s = RenderSettings(width=64, height=48, tile_size=16, crop=CROP, integrator="path")
    # Grid columns [0,16) [16,32) [32,48) [48,64), rows [0,16) [16,32) [32,48); index = row * 4 + col.
    expected = [(1, 20, 12, 12, 4), (2, 32, 12, 16, 4), (3, 48, 12, 4, 4),
                (5, 20, 16, 12, 16), (6, 32, 16, 16, 16), (7, 48, 16, 4, 16),
                (9, 20, 32, 12, 12), (10, 32, 32, 16, 12), (11, 48, 32, 4, 12)]
    assert [(t.index, t.x0, t.y0, t.width, t.height) for t in job_tiles(s)] == expected
    assert sum(t.width * t.height for t in job_tiles(s)) == (X1 - X0) * (Y1 - Y0)
    assert len(job_tiles(s.model_copy(update={"crop": None}))) == 12
    # Splatting integrators render the whole grid: a crop pixel gathers every pixel's light paths.
    for name in ("light", "bdpt", "vcm"):
        assert integrators.splats(name)
        assert len(job_tiles(s.model_copy(update={"integrator": name}))) == 12


# The Cornell box through a thin lens (f/2, focused inside the box): bdpt's splats then
# depend on the lens sample drawn after the camera subpath.
LENS_LAYER = """#usda 1.0
(
    subLayers = [@cornell.usda@]
    defaultPrim = "Cornell"
    renderSettingsPrimPath = "/Render/Settings"
)

over "Cornell"
{
    over "Camera"
    {
        float fStop = 2
        float focusDistance = 900
    }
}
"""
SPLATTING = ["bdpt", "light", "vcm", "bdpt-lens", "vcm-lens"]
PARAMS = {"vcm": {"light_paths": 3000}}  # a small scene pass: the crop leaves it whole anyway


@pytest.fixture(scope="module")
def lens_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lens")
    (folder / "cornell.usda").write_text(CORNELL.read_text())
    (folder / "lens.usda").write_text(LENS_LAYER)
    return folder / "lens.usda"


@pytest.fixture(scope="module")
def renders(lens_scene):
    out = {}
    for name in ("path", "sppm", "radiosity", *SPLATTING):
        integrator, _, camera = name.partition("-")
        scene = lens_scene if camera else CORNELL
        common = dict(spp=4, res=RES, integrator=integrator, tile_size=16, seed=5,
                      integrator_params=PARAMS.get(integrator))
        out[name] = tessera.render(scene, **common), tessera.render(scene, crop=CROP, **common)
        if integrator in ("bdpt", "vcm"):  # the control: another seed's crop
            out[name] += (tessera.render(scene, crop=CROP, **{**common, "seed": 6}),)
    return out


def test_the_lens_scene_has_a_lens(lens_scene):
    from tessera_renderer import load_scene

    assert load_scene(lens_scene).data.camera.lens_radius > 0
    assert load_scene(CORNELL).data.camera.lens_radius == 0


@pytest.mark.parametrize("name", ["path", "sppm", "radiosity", *SPLATTING])
def test_crop_pixels_equal_the_full_render_bit_for_bit(renders, name):
    full, crop = renders[name][:2]
    region = (slice(Y0, Y1), slice(X0, X1))
    assert np.array_equal(crop.rgba[region].view(np.uint32), full.rgba[region].view(np.uint32))
    assert float(crop.rgba[region][..., :3].mean()) > 0.01  # lit pixels, not two empty frames
    for layer in set(full.layers) | set(crop.layers):  # the noise estimate, where there is one
        assert np.array_equal(crop.layers[layer][region].view(np.uint32),
                              full.layers[layer][region].view(np.uint32)), layer
    # The check can fail: the next pixel column over differs from the region's.
    shifted = full.rgba[Y0:Y1, X0 + 1:X1 + 1]
    assert not np.array_equal(crop.rgba[region].view(np.uint32), shifted.view(np.uint32))


@pytest.mark.parametrize("name", ["bdpt", "vcm", "bdpt-lens", "vcm-lens"])
def test_another_seeds_crop_differs(renders, name):
    """The control of the bit-for-bit check: the crop's pixels are not the same whatever
    the sampler draws (another seed changes most of them)."""
    full, _, other_seed = renders[name]
    region = (slice(Y0, Y1), slice(X0, X1))
    differs = other_seed.rgba[region][..., :3] != full.rgba[region][..., :3]
    assert differs.any(axis=-1).mean() > 0.5


@pytest.mark.parametrize("name", ["path", "sppm", "radiosity", *SPLATTING])
def test_crop_leaves_the_pixels_outside_black(renders, name):
    full, crop = renders[name][:2]
    outside = np.ones(crop.rgba.shape[:2], bool)
    outside[Y0:Y1, X0:X1] = False
    assert not crop.rgba[outside].any()  # not rendered, and splats landing there dropped
    for layer in crop.layers.values():
        assert not layer[outside].any()
    assert full.rgba[outside].any()  # the check can fail: the full frame is lit there


@pytest.mark.parametrize("name", ["path", "sppm", "radiosity"])
def test_crop_renders_only_its_pixels(renders, name):
    full, crop = renders[name]
    area, full_area = (X1 - X0) * (Y1 - Y0), RES[0] * RES[1]
    assert crop.metadata["samples"] == area * 4 and full.metadata["samples"] == full_area * 4


@pytest.mark.parametrize("name", SPLATTING)
def test_a_splatting_crop_traces_every_pixels_light_paths(renders, name):
    full, crop = renders[name][:2]
    assert crop.metadata["samples"] == full.metadata["samples"] == RES[0] * RES[1] * 4


@pytest.mark.parametrize("integrator", ["bdpt", "path"])
def test_the_camera_window_skips_camera_work_outside_it_only(integrator):
    """A tile inside the camera window (here the right strip, x >= 40) and one left of it
    (seeing the box's back wall), rendered with the window and without: inside, the same
    pixels and rays; outside, black pixels, the same splats where they land in the window
    and none elsewhere, and for bdpt only its light subpaths and their splats' camera
    connections traced (closest-hit rays measured at 0.46-0.47 of the full render's, shadow
    rays 0.27-0.29, seeds 5-7: the bounds 0.6 and 0.4 fail if the camera subpath ran, ~1,
    or next event estimation from it, ~+0.3); path traces nothing there."""
    from tessera_renderer import load_scene

    scene = load_scene(CORNELL)
    w, h = RES
    window = (40, 0, w, h)
    splats = integrators.splats(integrator)

    def tile(x0, y0, camera_window):
        buffer = np.zeros((h, w, 3), np.int64) if splats else None
        stats = {}
        rgba = scene.render_tile(x0, y0, 16, 16, width=w, height=h, spp=4, seed=5, integrator=integrator,
                                 splats=buffer, stats=stats, camera_window=camera_window)
        return rgba, buffer, stats

    rays = ("closest_rays", "shadow_rays")
    (rgba, _, stats), (rgba_w, _, stats_w) = tile(48, 16, None), tile(48, 16, window)
    assert rgba[..., :3].any()
    assert np.array_equal(rgba.view(np.uint32), rgba_w.view(np.uint32))
    assert {k: stats[k] for k in rays} == {k: stats_w[k] for k in rays}
    (rgba, buffer, stats), (rgba_w, buffer_w, stats_w) = tile(16, 16, None), tile(16, 16, window)
    assert rgba[..., :3].any() and not rgba_w.any()
    if not splats:
        assert stats_w["closest_rays"] == stats_w["shadow_rays"] == stats_w["samples"] == 0
        return
    inside, outside = buffer[:, 40:], buffer[:, :40]
    assert inside.any() and outside.any()  # the checks below can fail
    assert np.array_equal(buffer_w[:, 40:], inside) and not buffer_w[:, :40].any()
    assert stats_w["samples"] == stats_w["light_paths"] == stats["light_paths"] == 16 * 16 * 4
    assert stats_w["closest_rays"] < 0.6 * stats["closest_rays"]
    assert stats_w["shadow_rays"] < 0.4 * stats["shadow_rays"]


def test_a_camera_window_outside_the_image_is_refused():
    from tessera_renderer import load_scene

    scene = load_scene(CORNELL)
    for bad, message in [((0, 0, 65, 8), "inside the image"), ((8, 4, 8, 9), "x0 < x1")]:
        with pytest.raises(ValueError, match=message):
            scene.render_tile(0, 0, 16, 16, width=64, height=48, spp=1, camera_window=bad)


def test_the_aovs_outside_the_camera_window_are_zero():
    """Outside the window every layer is 0, as for the pixels a cropped path render never
    reaches (the depth too, not the +inf of a pixel that saw nothing)."""
    from tessera_renderer import load_scene

    scene = load_scene(CORNELL)
    names = ("albedo", "normal", "depth", "spp")
    for window, expect_zero in (((40, 0, 64, 48), True), (None, False)):
        _, layers = scene.render_tile(16, 16, 16, 16, width=64, height=48, spp=2, seed=5, integrator="bdpt",
                                      splats=np.zeros((48, 64, 3), np.int64), aovs=names, camera_window=window)
        for name in names:
            assert (not layers[name].any()) == expect_zero, name  # without the window: the control
