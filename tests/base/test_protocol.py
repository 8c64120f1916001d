"""The shared job/tile schema: tile grid, tile result encoding, task messages."""
from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from tessera_base import protocol
from tessera_base import convergence
from tessera_queue import tasks as queue_tasks

from tessera_queue import redis_schema as rdb

from tessera_base import film
from tessera_base.protocol import RenderSettings, TileRect, decode_tile, encode_tile, tile_grid
from tessera_queue.tasks import TileTask


@pytest.mark.parametrize("width,height,tile", [(1, 1, 8), (7, 5, 8), (33, 17, 8), (100, 37, 16),
                                               (64, 64, 64), (65, 63, 64), (13, 200, 9)])
def test_tile_grid_covers_each_pixel_once(width, height, tile):
    grid = tile_grid(width, height, tile)
    cover = np.zeros((height, width), dtype=np.int32)
    for i, t in enumerate(grid):
        assert t.index == i
        assert 1 <= t.width <= tile and 1 <= t.height <= tile
        assert t.x0 + t.width <= width and t.y0 + t.height <= height
        cover[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] += 1
    assert (cover == 1).all()
    assert len(grid) == -(-width // tile) * -(-height // tile)


def test_tile_round_trip_is_bit_exact():
    rect = TileRect(index=3, x0=16, y0=8, width=5, height=3)
    rng = np.random.default_rng(1)
    rgba = rng.normal(size=(3, 5, 4)).astype(np.float32)
    rgba[0, 0] = [np.inf, -np.inf, np.nan, -0.0]
    r = decode_tile(encode_tile(rect, rgba))
    x0, y0, back = r.x0, r.y0, r.rgba
    assert (x0, y0, back.shape, back.dtype) == (16, 8, (3, 5, 4), np.float32)
    assert np.array_equal(back.view(np.uint32), rgba.view(np.uint32))


def test_encode_rejects_wrong_shape():
    rect = TileRect(index=0, x0=0, y0=0, width=4, height=2)
    with pytest.raises(ValueError, match="shape"):
        encode_tile(rect, np.zeros((4, 2, 4), np.float32))


def test_decode_rejects_truncated_and_garbage():
    rect = TileRect(index=0, x0=0, y0=0, width=4, height=4)
    data = encode_tile(rect, np.ones((4, 4, 4), np.float32))
    with pytest.raises(ValueError, match="truncated"):
        decode_tile(data[:10])
    with pytest.raises(ValueError, match="bytes"):
        decode_tile(data[:-1])
    with pytest.raises(ValueError, match="bytes"):
        decode_tile(data + b"\0")
    with pytest.raises(ValueError, match="format"):
        decode_tile(b"JUNK" + data[4:])
    with pytest.raises(ValueError):
        decode_tile(b"\xff" * 200)
    with pytest.raises(ValueError):
        decode_tile(b"")


def _task(**overrides) -> TileTask:
    values = dict(job_id="j1", scene_hash="ab" * 32, scene_name="cornell.usda",
                  settings=RenderSettings(width=72, height=56, spp=8, seed=3, max_depth=16, tile_size=16),
                  tile=TileRect(index=4, x0=64, y0=0, width=8, height=16))
    values.update(overrides)
    return TileTask(**values)


def test_task_fields_round_trip():
    task = _task()
    fields = task.to_fields()
    assert set(fields) == {"task"}
    assert TileTask.from_fields(fields) == task
    # as redis-py returns them: bytes keys and values
    assert TileTask.from_fields({b"task": fields["task"].encode()}) == task


def test_task_rejects_other_schema_version_and_bad_fields():
    raw = json.loads(_task().model_dump_json())
    raw["schema_version"] = 1
    with pytest.raises(ValidationError, match="schema_version"):
        TileTask.from_fields({"task": json.dumps(raw)})
    with pytest.raises(ValueError, match="no 'task'"):
        TileTask.from_fields({"other": "x"})
    with pytest.raises(ValidationError):
        TileTask.from_fields({"task": "{not json"})
    raw["schema_version"] = 2
    raw["settings"]["spp"] = 0
    with pytest.raises(ValidationError, match="spp"):
        TileTask.from_fields({"task": json.dumps(raw)})


def test_render_settings_limits():
    with pytest.raises(ValidationError, match="tile_size"):
        RenderSettings(width=8, height=8, tile_size=4)
    with pytest.raises(ValidationError, match="width"):
        RenderSettings(width=0, height=8)
    s = RenderSettings(width=8, height=8)
    assert (s.spp, s.seed, s.max_depth, s.tile_size) == (64, 0, 64, 64)
    assert not s.adaptive
    with pytest.raises(ValidationError, match="min_spp"):
        RenderSettings(width=8, height=8, target_error=0.01, min_spp=64, max_spp=32)
    with pytest.raises(ValidationError, match="target_error"):
        RenderSettings(width=8, height=8, target_error=0)


def test_pass_schedule():
    fixed = RenderSettings(width=8, height=8, spp=10)
    assert protocol.pass_range(fixed, 0) == (0, 10) and protocol.pass_range(fixed, 1) is None
    adaptive = RenderSettings(width=8, height=8, target_error=0.01, min_spp=16, max_spp=100)
    ranges = []
    p = 0
    while (r := protocol.pass_range(adaptive, p)) is not None:
        ranges.append(r)
        p += 1
    assert ranges == [(0, 16), (16, 16), (32, 32), (64, 36)]  # contiguous, capped at max_spp


def test_pass_schedule_stops_doubling_at_a_merging_integrators_cap():
    """vcm holds at most max_iteration_paths light paths an iteration, light_paths a batch
    and a first pass's share: 8000 / 2000 = 4 shares, so passes of 2 samples double to 8
    and stay there. sppm's default (1e5 photons a batch, at most 1e7): 64 shares. path: none."""
    def ranges(integrator, params, min_spp, max_spp):
        s = RenderSettings(width=8, height=8, target_error=0.01, min_spp=min_spp, max_spp=max_spp,
                           integrator=integrator, integrator_params=params)
        out, p = [], 0
        while (r := protocol.pass_range(s, p)) is not None:
            out.append(r)
            p += 1
        return out

    assert ranges("vcm", {"light_paths": 2000, "max_iteration_paths": 8000}, 2, 40) == [
        (0, 2), (2, 2), (4, 4), (8, 8), (16, 8), (24, 8), (32, 8)]
    assert ranges("vcm", {"light_paths": 3e6}, 1, 4) == [(0, 1), (1, 1), (2, 1), (3, 1)]
    assert ranges("sppm", {}, 1, 256) == [(0, 1), (1, 1), (2, 2), (4, 4), (8, 8), (16, 16), (32, 32),
                                          (64, 64), (128, 64), (192, 64)]
    assert ranges("path", {}, 1, 256)[-1] == (128, 128)


def test_a_fixed_spp_of_a_progressive_integrator_runs_the_noise_target_passes_from_one_sample():
    """sppm, vcm and photon_direct converge only as iterations add photons or light paths
    (issue 46: a fixed spp was one pass and plateaued): a fixed spp runs the passes of a
    noise target with min_spp 1 and max_spp = spp, all of them; other integrators keep one
    pass."""
    def ranges(integrator, spp, params=None):
        s = RenderSettings(width=8, height=8, spp=spp, integrator=integrator, integrator_params=params or {})
        out, p = [], 0
        while (r := protocol.pass_range(s, p)) is not None:
            out.append(r)
            p += 1
        return out

    assert ranges("vcm", 40, {"light_paths": 2000, "max_iteration_paths": 8000}) == [
        (0, 1), (1, 1), (2, 2), (4, 4), (8, 4), (12, 4), (16, 4), (20, 4), (24, 4), (28, 4), (32, 4), (36, 4)]
    assert ranges("sppm", 256) == [(0, 1), (1, 1), (2, 2), (4, 4), (8, 8), (16, 16), (32, 32), (64, 64),
                                   (128, 64), (192, 64)]
    assert ranges("sppm", 1) == [(0, 1)]
    assert ranges("vcm", 3) == [(0, 1), (1, 1), (2, 1)]
    # photon_direct: batches of 200000 photons, at most 2e6 an iteration (8 batches).
    assert ranges("photon_direct", 64) == [(0, 1), (1, 1), (2, 2), (4, 4), (8, 8), (16, 8), (24, 8), (32, 8),
                                           (40, 8), (48, 8), (56, 8)]
    for integrator in ("path", "bdpt", "auto"):
        assert ranges(integrator, 256) == [(0, 256)], integrator


def test_result_v2_round_trip_with_variance_and_splat():
    rect = TileRect(index=1, x0=4, y0=2, width=3, height=2)
    rng = np.random.default_rng(2)
    rgba = rng.random((2, 3, 4), dtype=np.float32)
    var = rng.random((2, 3, 3), dtype=np.float32)
    splat = rng.integers(0, 1 << 40, size=(5, 7, 3), dtype=np.int64)
    data = encode_tile(rect, rgba, pass_index=2, sample_start=32, spp=32, variance=var,
                       splat_rect=(0, 0, 7, 5), splat=splat, light_paths=12345)
    r = decode_tile(data)
    assert (r.pass_index, r.sample_start, r.spp, r.light_paths, r.splat_rect) == (2, 32, 32, 12345, (0, 0, 7, 5))
    assert np.array_equal(r.rgba, rgba) and np.array_equal(r.variance, var)
    assert r.splat.dtype == np.int64 and np.array_equal(r.splat, splat)
    with pytest.raises(ValueError, match="bytes"):
        decode_tile(data[:-4])
    with pytest.raises(ValueError, match="variance"):
        encode_tile(rect, rgba, variance=var[:1])


def test_version_1_results_are_still_read():
    import struct
    rgba = np.arange(2 * 2 * 4, dtype=np.float32).reshape(2, 2, 4)
    data = struct.pack("<4sIiiii", b"TSRT", 1, 8, 16, 2, 2) + rgba.tobytes()
    r = decode_tile(data)
    assert (r.x0, r.y0) == (8, 16) and np.array_equal(r.rgba, rgba) and r.variance is None


def test_combine_passes_matches_the_pooled_statistics():
    """Two passes combine to the mean and the unbiased variance of all their samples."""
    rng = np.random.default_rng(3)
    samples = rng.normal(1.0, 0.5, size=(40, 2, 2, 4))
    def result(chunk, p, start):
        return protocol.TileResult(0, 0, chunk.mean(0).astype(np.float32), p, start, len(chunk),
                                   chunk[..., :3].var(0, ddof=1).astype(np.float32))
    a, b = result(samples[:16], 0, 0), result(samples[16:], 1, 16)
    mean, var, n = convergence.combine_passes([b, a])  # order does not matter
    assert n == 40
    assert np.allclose(mean, samples.mean(0), atol=1e-6)
    assert np.allclose(var, samples[..., :3].var(0, ddof=1), rtol=1e-5)
    # One pass is returned untouched (bit-identical to a single render).
    assert convergence.combine_passes([a])[0] is a.rgba


def test_noise_target_decision():
    s = RenderSettings(width=8, height=8, target_error=0.01, min_spp=16, max_spp=64)
    flat = np.ones((4, 4, 4), np.float32)
    # Background (no variance at all) is finished after its first pass.
    assert convergence.tile_finished(s, 0, flat, np.zeros((4, 4, 3), np.float32), 16)
    # Luminance standard error / luminance = sqrt(sum(w^2) * 0.16 / 16) / 1 = 7.5 % > 1 %:
    # go on ...
    noisy = np.full((4, 4, 3), 0.16, np.float32)
    w = np.array([0.2126, 0.7152, 0.0722])
    assert convergence.tile_error(flat, noisy, 16) == pytest.approx(np.sqrt((w ** 2).sum() * 0.01))
    assert not convergence.tile_finished(s, 0, flat, noisy, 16)
    # ... until the last pass of the schedule (64 spp), whatever the noise.
    assert convergence.tile_finished(s, 2, flat, noisy, 64)
    assert convergence.tile_finished(s, 1, flat, noisy / 1e4, 32)


def test_key_layout_is_namespaced():
    keys = [rdb.READY, rdb.ACTIVE, rdb.STATS, rdb.WORKERS, rdb.DEAD_LETTER,
            rdb.JOB_INDEX, *rdb.job_keys("j"), rdb.preflight_key("h", ".usda"),
            rdb.scene_key("h"), rdb.scene_jobs_key("h"), rdb.worker_key("w")]
    assert all(k.startswith(rdb.PREFIX + ":") for k in keys)
    assert len(set(keys)) == len(keys)


def test_splat_scale_is_the_renderers():
    """The farm normalises splats with film.SPLAT_SCALE; it must be the renderer's."""
    from tessera_renderer import _core
    assert film.SPLAT_SCALE == _core.SPLAT_SCALE


def test_compressed_splat_layers_round_trip_and_merge_exactly():
    rng = np.random.default_rng(1)
    frame = np.zeros((30, 40, 3), np.int64)
    frame[5:20, 7:33] = rng.integers(0, 1 << 40, size=(15, 26, 3))
    rect, layer = film.splat_layer(frame)
    assert rect == (7, 5, 26, 15)
    tile = protocol.TileRect(index=0, x0=0, y0=0, width=8, height=4)
    data = protocol.encode_tile(tile, np.zeros((4, 8, 4), np.float32), spp=2, splat_rect=rect, splat=layer,
                                light_paths=64)
    assert len(data) < layer.nbytes  # compressed
    result = protocol.decode_tile(data)
    assert result.light_paths == 64 and result.splat_rect == rect
    total = np.zeros_like(frame)
    film.add_splats(total, result.splat_rect, result.splat)
    assert np.array_equal(total, frame)
    # A corrupted splat section is an error, not garbage pixels.
    with pytest.raises(ValueError):
        protocol.decode_tile(data[:-5] + b"xxxxx")
    # Nothing landed: an empty rectangle.
    assert film.splat_layer(np.zeros((4, 4, 3), np.int64))[0] == (0, 0, 0, 0)


def test_splat_unit_exponent_round_trips_and_scales_the_image():
    tile = protocol.TileRect(index=0, x0=0, y0=0, width=2, height=1)
    layer = np.full((1, 2, 3), 1 << 24, np.int64)  # one unit per channel
    results = []
    for exponent in (-90, 0, 70):
        data = protocol.encode_tile(tile, np.zeros((1, 2, 4), np.float32), spp=1,
                                    splat_rect=(0, 0, 2, 1), splat=layer, light_paths=2,
                                    splat_exponent=exponent)
        r = protocol.decode_tile(data)
        assert r.splat_exponent == exponent
        image = film.resolve_splats(np.zeros((1, 2, 4), np.float32), r.splat, 2, r.splat_exponent)
        assert np.allclose(image[..., :3], 2.0 ** exponent, rtol=1e-6)
        results.append(r)
    assert film.splat_exponent_of(results[:1]) == -90
    with pytest.raises(ValueError, match="splat unit"):
        film.splat_exponent_of(results)


def test_integrators_that_cannot_stop_per_tile_take_noise_targets_in_lockstep():
    """Lockstep follows the registry's stop_per_tile capability; `auto` is scheduled in
    lockstep because one of the integrators it may pick cannot stop per tile. A fixed spp
    is lockstep only for the progressive integrators (an iteration_cap: sppm, vcm,
    photon_direct), whose fixed spp runs in passes."""
    from tessera_renderer import _core
    registry = _core.integrators()
    assert {i["stop_per_tile"] for i in registry} == {True, False}  # both kinds are exercised
    progressive = {i["name"] for i in registry if i.get("iteration_cap")}
    assert progressive == {"sppm", "vcm", "photon_direct"}
    for info in registry:
        s = protocol.RenderSettings(width=8, height=8, target_error=0.05, integrator=info["name"])
        assert s.adaptive and s.lockstep == (not info["stop_per_tile"]), info["name"]
        fixed = protocol.RenderSettings(width=8, height=8, integrator=info["name"])
        assert fixed.lockstep == (info["name"] in progressive), info["name"]
    assert not protocol.RenderSettings(width=8, height=8, integrator="auto").lockstep
    auto_picks = {_core.auto_integrator(False), _core.auto_integrator(True)}
    assert not all(i["stop_per_tile"] for i in registry if i["name"] in auto_picks)
    assert protocol.RenderSettings(width=8, height=8, target_error=0.05, integrator="auto").lockstep


def test_integrator_names_come_from_the_registry():
    from tessera_renderer import _core
    names = [i["name"] for i in _core.integrators()]
    assert protocol.RenderSettings(width=8, height=8).integrator == names[0]
    for name in names + ["auto"]:
        assert protocol.RenderSettings(width=8, height=8, integrator=name).integrator == name
    with pytest.raises(ValueError, match="unknown integrator 'pathh'.*known: " + ", ".join(names)):
        protocol.RenderSettings(width=8, height=8, integrator="pathh")


def test_pass_accumulator_estimates_the_variance_of_the_mean():
    """Batch means over passes of unequal size: the estimated standard error of the
    weighted mean matches the true one (known sigma) within its own sampling error."""
    rng = np.random.default_rng(7)
    sigma, mu, counts = 0.3, 2.0, [16, 16, 32, 64]
    acc = convergence.PassAccumulator()
    for n in counts:  # each pass image: mean of n samples, per pixel, luminance mu
        lum = mu + rng.normal(0.0, sigma / np.sqrt(n), size=(64, 64))
        acc = acc.add(np.repeat(lum[..., None], 4, axis=2).astype(np.float32), n)
        # The luminance of a grey pixel is its value: weights sum to 1.
    true_rel = sigma / np.sqrt(sum(counts)) / mu
    # 3 degrees of freedom per pixel, averaged over 4096 pixels: a few per cent.
    assert acc.error() == pytest.approx(true_rel, rel=0.05)
    again = convergence.PassAccumulator.from_bytes(acc.to_bytes())
    assert again.passes == 4 and again.samples == sum(counts) and again.error() == acc.error()
    assert convergence.PassAccumulator().error() is None
    assert convergence.PassAccumulator().add(np.ones((2, 2, 4), np.float32), 4).error() is None


def test_image_finished_follows_the_schedule_and_the_target():
    s = protocol.RenderSettings(width=8, height=8, target_error=0.05, min_spp=4, max_spp=16,
                                integrator="bdpt")
    flat = np.ones((8, 8, 4), np.float32)
    one = convergence.PassAccumulator().add(flat, 4)
    assert not convergence.image_finished(s, 0, one)  # one pass cannot judge its noise
    noiseless = one.add(flat, 4)
    assert convergence.image_finished(s, 1, noiseless)
    noisy = one.add(flat * 3, 4)
    assert not convergence.image_finished(s, 1, noisy)
    assert convergence.image_finished(s, 2, noisy.add(flat, 8))  # 16 = max_spp: the last pass


def test_pass_tasks_cover_the_grid_and_the_barrier_is_marked():
    spec = protocol.JobSpec(job_id="j", scene_hash="h", scene_name="s.usda",
                            settings=protocol.RenderSettings(width=20, height=10, tile_size=8,
                                                             target_error=0.1, integrator="light"))
    first = queue_tasks.job_tasks(spec)[3]
    barrier = queue_tasks.TileTask.from_fields(first.decide_task().to_fields())
    assert barrier.decide and barrier.pass_index == 0
    nxt = barrier.pass_tasks(1)
    assert [t.tile for t in nxt] == protocol.tile_grid(20, 10, 8)
    assert all(t.pass_index == 1 and not t.decide and t.job_id == "j" for t in nxt)




def test_variance_batches_round_trip_and_split_every_pass():
    """FLAG_BATCHES: each batch's spp, light paths, camera part and splat layer come back
    exactly; a reader of results without the flag sees none; a cut result is refused."""
    assert convergence.batch_ranges(0, 16) == [(2 * j, 2) for j in range(8)]
    assert convergence.batch_ranges(16, 3) == [(16, 1), (17, 1), (18, 1)]
    assert sum(n for _, n in convergence.batch_ranges(5, 37)) == 37
    rng = np.random.default_rng(3)
    rect = TileRect(index=1, x0=8, y0=0, width=4, height=3)
    batches = [protocol.SplatBatch(2, rng.random((3, 4, 3), dtype=np.float32), (1, 2, 5, 2),
                                   rng.integers(0, 1 << 40, (2, 5, 3)), 24) for _ in range(3)]
    data = encode_tile(rect, np.ones((3, 4, 4), np.float32), spp=6, batches=batches,
                       splat_rect=(0, 0, 1, 1), splat=np.ones((1, 1, 3), np.int64), light_paths=72)
    back = decode_tile(data)
    assert len(back.batches) == 3 and back.splat is not None
    for b, o in zip(back.batches, batches):
        assert (b.spp, b.light_paths, b.splat_rect) == (o.spp, o.light_paths, o.splat_rect)
        assert b.rgb.tobytes() == o.rgb.tobytes() and (b.splat == o.splat).all()
    assert decode_tile(encode_tile(rect, np.ones((3, 4, 4), np.float32), spp=6)).batches is None
    with pytest.raises(ValueError):
        decode_tile(data[:-3])


def test_batch_variance_is_the_spread_of_batch_images():
    """film.batch_variance of one tile without splats equals the weighted sample
    variance of its batch means divided by the batch count (equal batches)."""
    rng = np.random.default_rng(4)
    k, h, w = 6, 2, 3
    means = rng.random((k, h, w, 3)).astype(np.float32)
    result = protocol.TileResult(0, 0, np.zeros((h, w, 4), np.float32), spp=4 * k, batches=[
        protocol.SplatBatch(4, means[j], (0, 0, 0, 0), np.zeros((0, 0, 3), np.int64), 4 * h * w)
        for j in range(k)])
    var, batches = film.batch_variance(w, h, [result])
    assert batches == k
    np.testing.assert_allclose(var, means.astype(np.float64).var(axis=0, ddof=1) / k, rtol=1e-5)


def test_frame_lists_read_as_render_farms_write_them():
    from tessera_base.protocol import parse_frames

    assert parse_frames("1-5") == [1, 2, 3, 4, 5]
    assert parse_frames("1-24x5") == [1, 6, 11, 16, 21]
    assert parse_frames("7") == [7]
    assert parse_frames("10,1-3, 2, 20-22x2") == [10, 1, 2, 3, 20, 22]  # as written, each once
    assert parse_frames("-3--1") == [-3, -2, -1]
    for bad in ("", "1-", "a", "5-1", "1-5x0", "1.5", "1-1000000"):
        with pytest.raises(ValueError, match="frames"):
            parse_frames(bad)


def test_numbered_paths_put_the_frame_where_the_hashes_are():
    from tessera_base.protocol import numbered_path

    assert numbered_path("out/shot.####.exr", 7) == "out/shot.0007.exr"
    assert numbered_path("shot_##.exr", 123) == "shot_123.exr"
    assert numbered_path("out/shot.exr", 12) == "out/shot.0012.exr"
    assert numbered_path("dir.v2/shot.exr", -3) == "dir.v2/shot.-0003.exr"


def test_variant_selections_are_prim_set_and_variant():
    from tessera_base.protocol import parse_variant

    assert parse_variant("/Car:wheels=sedan") == ("/Car", "wheels", "sedan")
    assert parse_variant(" /World/Car_1:look=") == ("/World/Car_1", "look", "")  # "" clears the selection
    for bad in ("Car:wheels=sedan", "/Car:wheels", "/Car/:wheels=sedan", "/Car:a=b=c", "/Car:a/b=c", "/Car wheels"):
        with pytest.raises(ValueError, match="must be /Prim/Path:set=value"):
            parse_variant(bad)
    assert RenderSettings(width=8, height=8, variants=["/Car:wheels=sedan"]).variants == ["/Car:wheels=sedan"]
    assert RenderSettings(width=8, height=8, variants=[]).variants is None
    with pytest.raises(ValueError, match="must be /Prim/Path:set=value"):
        RenderSettings(width=8, height=8, variants=["wheels=sedan"])


def test_a_spec_written_before_seed_offset_still_reads_and_draws_its_own_seed():
    """Schema 2 without seed_offset (as a farm before it stored jobs in Redis): it reads,
    and its samples use its seed unchanged, so its image keeps its bits."""
    old = ('{"schema_version": 2, "job_id": "' + "a" * 32 + '", "scene_hash": "' + "b" * 64 + '", '
           '"scene_name": "s.usda", "settings": {"width": 8, "height": 8, "spp": 4, "seed": 9}}')
    spec = protocol.JobSpec.model_validate_json(old)
    assert spec.settings.seed_offset == 0 and spec.settings.sample_seed == 9
    # The control: an offset changes the seed drawn, modulo 2^32.
    later = spec.settings.model_copy(update={"seed_offset": 2**32 - 8})
    assert later.sample_seed == 1


def test_the_time_limit_stops_a_noise_target_render_at_its_second_and_never_a_fixed_spp():
    """convergence's one time-limit check, as local renders and workers call it (the clock
    is passed in: no waiting here)."""
    def never():
        raise AssertionError("the clock was read although nothing depends on it")

    s = RenderSettings(width=8, height=8, target_error=0.01, min_spp=16, max_spp=64, time_limit=10)
    flat = np.ones((4, 4, 4), np.float32)
    noisy = np.full((4, 4, 3), 0.16, np.float32)  # 7.5 % noise: the target is not reached
    assert not convergence.tile_stops(s, 0, flat, noisy, 16, lambda: 9.99)
    assert convergence.tile_stops(s, 0, flat, noisy, 16, lambda: 10.0)
    assert not convergence.tile_stops(s, 0, flat, noisy, 16, lambda: None)  # start unknown
    assert convergence.tile_stops(s, 0, flat, noisy / 1e4, 16, never)  # the noise stopped it
    fixed = RenderSettings(width=8, height=8, spp=16, time_limit=10)
    assert not convergence.time_is_up(fixed, never)  # a fixed spp renders every pass
    assert not convergence.time_is_up(s.model_copy(update={"time_limit": None}), never)
    one = convergence.PassAccumulator().add(np.ones((4, 4, 4), np.float32), 16)
    assert not convergence.image_stops(s, 0, one, lambda: 9.99)  # one pass cannot judge its noise
    assert convergence.image_stops(s, 0, one, lambda: 10.0)
