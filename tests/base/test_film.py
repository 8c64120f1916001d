"""tessera_base.film (one tile pass, one image assembly, splat sums) and tessera_queue.redis_schema
(the scripts load and compile on a real Redis)."""
from __future__ import annotations

import numpy as np
import pytest

from tessera_base import film
from tessera_queue import redis_schema as rdb
from tessera_base.protocol import RenderSettings, TileResult, tile_grid


def _results(settings: RenderSettings, seed: int = 0) -> dict[int, list[TileResult]]:
    """One splatting pass of every tile, with random camera parts and splat layers."""
    rng = np.random.default_rng(seed)
    out = {}
    for t in tile_grid(settings.width, settings.height, settings.tile_size):
        rgba = rng.random((t.height, t.width, 4), dtype=np.float32)
        frame = rng.integers(-1000, 1 << 30, size=(settings.height, settings.width, 3))
        frame[rng.random(frame.shape[:2]) < 0.5] = 0
        rect, layer = film.splat_layer(frame)
        out[t.index] = [TileResult(t.x0, t.y0, rgba, 0, 0, settings.spp, splat_rect=rect, splat=layer,
                                   light_paths=t.width * t.height * settings.spp, splat_exponent=-3)]
    return out


def test_splat_sums_round_trip_exactly():
    sums = film.SplatSums(7, 5)
    layer = sums.layer("0")
    layer[1:4, 2:6] = np.arange(36).reshape(3, 4, 3) * (-1) ** np.arange(36).reshape(3, 4, 3) << 33
    back = film.SplatSums(7, 5)
    back.decode_into("0", sums.encode("0"))
    assert np.array_equal(back.layers["0"], layer)
    empty = film.SplatSums(7, 5)
    empty.decode_into("1", film.SplatSums(7, 5).encode("1"))
    assert not empty.layers["1"].any()
    with pytest.raises(ValueError):
        film.SplatSums(5, 5).decode_into("0", sums.encode("0"))  # does not fit a smaller frame
    with pytest.raises(ValueError):
        back.decode_into("0", sums.encode("0")[:-3])


def test_folded_results_assemble_to_the_same_image_in_any_order():
    """Folding every tile's splats into the sums (in any order) and assembling gives the
    image of the unfolded results bit for bit. Control: a tile folded twice (a pass summed
    on two deliveries) changes the image, so the check sees double counting."""
    s = RenderSettings(width=40, height=24, spp=4, tile_size=16, integrator="bdpt")
    results = _results(s)
    direct = film.assemble_image(s, results).rgba
    for order in (sorted(results), sorted(results, reverse=True)):
        sums = film.SplatSums(s.width, s.height)
        folded = {i: [sums.fold(results[i][0])] for i in order}
        assert all(r[0].splat.size == 0 for r in folded.values())
        restored = film.SplatSums.from_fields(s.width, s.height, {k: sums.encode(k) for k in sums.layers})
        image = film.assemble_image(s, folded, restored).rgba
        assert np.array_equal(image.view(np.uint32), direct.view(np.uint32))
    sums.fold(results[0][0])
    twice = film.assemble_image(s, folded, sums).rgba
    assert not np.array_equal(twice, direct)


def test_storage_bound_grows_with_pixels_not_tiles():
    small_tiles = RenderSettings(width=256, height=256, spp=16, tile_size=16, integrator="bdpt")
    large_tiles = small_tiles.model_copy(update={"tile_size": 128})
    ratio = rdb.job_storage_bound(small_tiles) / rdb.job_storage_bound(large_tiles)
    assert ratio < 1.2
    assert rdb.job_storage_bound(small_tiles.model_copy(update={"width": 512})) > 1.9 * rdb.job_storage_bound(small_tiles)


def test_every_script_compiles_on_redis(redis_client):
    """The .lua files ship with the package and load once; SCRIPT LOAD compiles them, so
    a syntax error or an unfilled constant fails here."""
    scripts = rdb.Scripts(redis_client)
    for name in rdb.JOB_SCRIPTS + rdb.OTHER_SCRIPTS:
        script = getattr(scripts, name)
        assert redis_client.script_load(script.script) == script.sha
    # A job script touching a missing job does nothing and says so.
    keys = rdb.job_script_keys("0" * 32, "none")
    assert scripts.cancel_job(keys=keys, args=["0" * 32, "0"]) == b""
    assert not redis_client.exists(*keys[:9])
