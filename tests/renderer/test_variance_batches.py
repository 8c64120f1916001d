"""A splatting integrator's variance batches, made in the same pass as the image.

The batches (convergence.VARIANCE_BATCHES sub-ranges of a pass's samples, each a whole
image of its own) used to be rendered by K extra calls after the pass, every sample
twice. Now one call routes each sample's splats and camera mean to its batch. The
reference here is what the old way computes: a separate render of each batch's sample
range alone, and the pass rendered without batches. Both must be met bit for bit; a
batch split that is off by one sample must not be.
"""
import numpy as np
import pytest

from tessera_base.convergence import batch_ranges
from tessera_base.film import SplatSums, render_tile_pass, splat_layer
from tessera_base.protocol import RenderSettings, TileRect, tile_grid
from tessera_renderer import load_scene
from tessera_renderer.film import new_splat_buffer

W, H = 24, 20
TILE = TileRect(index=0, x0=8, y0=0, width=12, height=10)  # holds the light, seen directly


@pytest.fixture(scope="module")
def scene(cornell_path):
    return load_scene(cornell_path)


def _alone(scene, integrator, start, n, seed=3):
    """A render of samples [start, start + n) of the tile alone: (camera RGB, splat buffer)."""
    splats = new_splat_buffer(W, H)
    rgba = scene.render_tile(TILE.x0, TILE.y0, TILE.width, TILE.height, width=W, height=H, spp=n,
                             sample_start=start, seed=seed, threads=2, integrator=integrator, splats=splats)
    return rgba[..., :3], splats


@pytest.mark.parametrize("integrator", ["bdpt", "light"])
def test_one_pass_batches_equal_each_batch_rendered_alone(scene, integrator):
    start, spp = 5, 11  # 8 batches of 2, 2, 2, 1, 1, 1, 1, 1 samples
    ranges = batch_ranges(start, spp)
    assert [n for _, n in ranges] == [2, 2, 2, 1, 1, 1, 1, 1]
    batch_splats = np.zeros((len(ranges), H, W, 3), np.int64)
    batch_rgb = np.empty((len(ranges), TILE.height, TILE.width, 3), np.float32)
    pass_splats = new_splat_buffer(W, H)
    rgba = scene.render_tile(TILE.x0, TILE.y0, TILE.width, TILE.height, width=W, height=H, spp=spp,
                             sample_start=start, seed=3, threads=2, integrator=integrator, splats=pass_splats,
                             batch_splats=batch_splats, batch_rgb=batch_rgb)
    for k, (b_start, n) in enumerate(ranges):
        rgb, splats = _alone(scene, integrator, b_start, n)
        assert np.array_equal(batch_rgb[k], rgb), f"batch {k}: camera mean"
        assert np.array_equal(batch_splats[k], splats), f"batch {k}: splats"
        assert splats.any() and rgb.any()
    # The image and its splat layer are those of the pass rendered without batches.
    rgb, splats = _alone(scene, integrator, start, spp)
    assert np.array_equal(rgba[..., :3], rgb)
    assert np.array_equal(pass_splats, splats) and np.array_equal(batch_splats.sum(axis=0), splats)
    # Control: a batch boundary one sample off is seen (batch 0 against samples 5..7).
    rgb, splats = _alone(scene, integrator, start, 3)
    assert not np.array_equal(batch_rgb[0], rgb)
    assert not np.array_equal(batch_splats[0], splats)


def test_the_tile_pass_carries_the_same_batches_and_image_as_before(scene):
    """render_tile_pass with batches (what `tessera render` and the farm's variance AOV
    run) against the pass without batches and each batch's range rendered alone."""
    settings = RenderSettings(width=W, height=H, spp=9, seed=3, integrator="bdpt", tile_size=12)
    with_b, _ = render_tile_pass(scene, settings, TILE, 0, integrator="bdpt", threads=2, batches=True)
    without, _ = render_tile_pass(scene, settings, TILE, 0, integrator="bdpt", threads=2)
    assert without.batches is None or not without.batches
    assert np.array_equal(with_b.rgba, without.rgba)
    assert with_b.splat_rect == without.splat_rect and np.array_equal(with_b.splat, without.splat)
    assert with_b.light_paths == without.light_paths == TILE.width * TILE.height * 9
    ranges = batch_ranges(0, 9)
    assert len(with_b.batches) == len(ranges)
    for batch, (start, n) in zip(with_b.batches, ranges):
        rgb, splats = _alone(scene, "bdpt", start, n)
        rect, layer = splat_layer(splats)
        assert batch.spp == n and batch.light_paths == TILE.width * TILE.height * n
        assert np.array_equal(batch.rgb, rgb)
        assert batch.splat_rect == rect and np.array_equal(batch.splat, layer)


def test_bad_batch_requests_are_refused(scene):
    rgb = np.empty((2, TILE.height, TILE.width, 3), np.float32)
    kw = dict(width=W, height=H, seed=3, threads=1)
    with pytest.raises(ValueError, match="integrators that splat"):
        scene.render_tile(TILE.x0, TILE.y0, TILE.width, TILE.height, spp=4, integrator="path",
                          batch_splats=np.zeros((2, H, W, 3), np.int64), batch_rgb=rgb, **kw)
    with pytest.raises(ValueError, match="1 to spp batches"):
        scene.render_tile(TILE.x0, TILE.y0, TILE.width, TILE.height, spp=1, integrator="bdpt",
                          batch_splats=np.zeros((2, H, W, 3), np.int64), batch_rgb=rgb, **kw)
    with pytest.raises(ValueError, match="shape"):
        scene.render_tile(TILE.x0, TILE.y0, TILE.width, TILE.height, spp=4, integrator="bdpt",
                          batch_splats=np.zeros((2, H, W + 1, 3), np.int64), batch_rgb=rgb, **kw)


def test_splats_added_into_the_job_sums_equal_the_folded_tile_layers(scene):
    """The local render adds each tile's splats straight into the job's SplatSums
    (render_tile_pass `into`); the farm folds each tile's own layers. Over a 2 x 2 grid and
    two passes, every field (the passes' and their batches') must be the same to the bit."""
    settings = RenderSettings(width=W, height=H, spp=6, seed=3, integrator="bdpt", tile_size=12,
                              target_error=0.01, min_spp=3, max_spp=6)
    direct, folded = SplatSums(W, H), SplatSums(W, H)
    for p in (0, 1):
        for t in tile_grid(W, H, 12):
            a, _ = render_tile_pass(scene, settings, t, p, integrator="bdpt", threads=2, batches=True, into=direct)
            b, _ = render_tile_pass(scene, settings, t, p, integrator="bdpt", threads=2, batches=True)
            assert a.splat_rect == (0, 0, 0, 0) and all(x.splat_rect == (0, 0, 0, 0) for x in a.batches)
            b = folded.fold(b)
            assert np.array_equal(a.rgba, b.rgba) and a.light_paths == b.light_paths
            assert all(np.array_equal(x.rgb, y.rgb) for x, y in zip(a.batches, b.batches))
    assert sorted(direct.layers) == sorted(folded.layers) == sorted(
        [str(p) for p in (0, 1)] + [f"{p}:{j}" for p in (0, 1) for j in range(3)])
    for name, layer in folded.layers.items():
        assert layer.any() and np.array_equal(direct.layers[name], layer), name
    # Control: one tile's splats left out of the direct sums is seen.
    lone = SplatSums(W, H)
    render_tile_pass(scene, settings, tile_grid(W, H, 12)[0], 0, integrator="bdpt", threads=2, into=lone)
    assert not np.array_equal(lone.layers["0"], folded.layers["0"])
