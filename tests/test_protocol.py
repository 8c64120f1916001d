"""The shared job/tile schema: tile grid, tile result encoding, task messages."""
from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from tessera import protocol
from tessera.protocol import RenderSettings, TileRect, TileTask, decode_tile, encode_tile, tile_grid


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
    x0, y0, back = decode_tile(encode_tile(rect, rgba))
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
    raw["schema_version"] = 2
    with pytest.raises(ValidationError, match="schema_version"):
        TileTask.from_fields({"task": json.dumps(raw)})
    with pytest.raises(ValueError, match="no 'task'"):
        TileTask.from_fields({"other": "x"})
    with pytest.raises(ValidationError):
        TileTask.from_fields({"task": "{not json"})
    raw["schema_version"] = 1
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


def test_key_layout_is_namespaced():
    keys = [protocol.TILE_STREAM, protocol.JOB_INDEX, protocol.scene_key("h"), protocol.job_key("j"),
            protocol.job_tiles_key("j"), protocol.job_image_key("j", "exr"), protocol.worker_key("w")]
    assert all(k.startswith(protocol.PREFIX + ":") for k in keys)
    assert len(set(keys)) == len(keys)
