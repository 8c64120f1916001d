"""The one job/tile message schema shared by the service and the workers.

Everything that crosses Redis is declared here and nowhere else: the message models
(versioned), the tile grid, the key layout and the encoding of tile results. The service
writes jobs and tile tasks; workers read tasks and write results; both import this module.

Invariant: a pixel's value depends only on (scene, pixel, sample index, seed), so the
tile grid is a scheduling choice and never changes the image.
"""
from __future__ import annotations

import struct
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

SCHEMA_VERSION = 1

# Redis key layout. Everything Tessera stores lives under this prefix.
PREFIX = "tessera"
TILE_STREAM = f"{PREFIX}:tiles"          # stream of TileTask messages
WORKER_GROUP = "workers"                  # the consumer group every worker joins
JOB_INDEX = f"{PREFIX}:jobs"              # sorted set: job id -> creation time


def scene_key(scene_hash: str) -> str:
    """Hash {name, data}: a scene stored once per content hash."""
    return f"{PREFIX}:scene:{scene_hash}"


def job_key(job_id: str) -> str:
    """Hash: the job's spec (JSON), state, counters and timings. Fields:
    spec (JobSpec JSON), state (JobState), tiles_total, warnings (JSON list of str),
    error (set when failed), created_at / started_at / finished_at (unix seconds),
    render_seconds (sum of the render times of the stored tiles)."""
    return f"{PREFIX}:job:{job_id}"


def job_tiles_key(job_id: str) -> str:
    """Hash: tile index -> encoded tile result. Keyed by index so a tile rendered twice
    (at-least-once delivery) is stored once."""
    return f"{PREFIX}:job:{job_id}:tiles"


def job_image_key(job_id: str, fmt: Literal["exr", "png"]) -> str:
    """String: the merged image of a done job (EXR or PNG preview bytes), cached by the
    service so that repeated downloads do not re-merge the tiles."""
    return f"{PREFIX}:job:{job_id}:image.{fmt}"


def worker_key(worker_name: str) -> str:
    """String with a TTL: present while the worker is alive (its heartbeat)."""
    return f"{PREFIX}:worker:{worker_name}"


JobState = Literal["queued", "running", "done", "failed", "cancelled"]
FINAL_STATES = ("done", "failed", "cancelled")


class RenderSettings(BaseModel):
    """What to render. Resolution is final here (scene defaults already applied)."""

    width: int = Field(ge=1, le=16384)
    height: int = Field(ge=1, le=16384)
    spp: int = Field(default=64, ge=1, le=1 << 20)
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    max_depth: int = Field(default=64, ge=1, le=1024)
    tile_size: int = Field(default=64, ge=8, le=4096)


class TileRect(BaseModel):
    index: int = Field(ge=0)
    x0: int = Field(ge=0)
    y0: int = Field(ge=0)
    width: int = Field(ge=1)
    height: int = Field(ge=1)


class JobSpec(BaseModel):
    schema_version: Literal[1] = SCHEMA_VERSION
    job_id: str
    scene_hash: str
    scene_name: str  # the uploaded file name; its suffix tells USD the format
    settings: RenderSettings


class TileTask(BaseModel):
    """One stream message: everything a worker needs to render one tile."""

    schema_version: Literal[1] = SCHEMA_VERSION
    job_id: str
    scene_hash: str
    scene_name: str
    settings: RenderSettings
    tile: TileRect

    def to_fields(self) -> dict[str, str]:
        return {"task": self.model_dump_json()}

    @classmethod
    def from_fields(cls, fields: dict) -> "TileTask":
        raw = fields.get(b"task", fields.get("task"))
        if raw is None:
            raise ValueError("stream entry has no 'task' field")
        return cls.model_validate_json(raw)


def tile_grid(width: int, height: int, tile_size: int) -> list[TileRect]:
    """Row-major tiles covering the image; edge tiles are smaller."""
    tiles = []
    for y0 in range(0, height, tile_size):
        for x0 in range(0, width, tile_size):
            tiles.append(TileRect(index=len(tiles), x0=x0, y0=y0,
                                  width=min(tile_size, width - x0),
                                  height=min(tile_size, height - y0)))
    return tiles


# Tile result encoding: a fixed header then float32 RGBA pixels, row-major.
_TILE_HEADER = struct.Struct("<4sIiiii")  # magic, version, x0, y0, width, height
_TILE_MAGIC = b"TSRT"


def encode_tile(rect: TileRect, rgba: np.ndarray) -> bytes:
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    if rgba.shape != (rect.height, rect.width, 4):
        raise ValueError(f"tile {rect.index}: pixels have shape {rgba.shape}, "
                         f"expected {(rect.height, rect.width, 4)}")
    header = _TILE_HEADER.pack(_TILE_MAGIC, SCHEMA_VERSION, rect.x0, rect.y0,
                               rect.width, rect.height)
    return header + rgba.tobytes()


def decode_tile(data: bytes) -> tuple[int, int, np.ndarray]:
    """Returns (x0, y0, rgba[h, w, 4])."""
    if len(data) < _TILE_HEADER.size:
        raise ValueError("tile result is truncated")
    magic, version, x0, y0, w, h = _TILE_HEADER.unpack_from(data)
    if magic != _TILE_MAGIC or version != SCHEMA_VERSION:
        raise ValueError(f"tile result has unknown format {magic!r} v{version}")
    expected = _TILE_HEADER.size + w * h * 4 * 4
    if len(data) != expected:
        raise ValueError(f"tile result has {len(data)} bytes, expected {expected}")
    rgba = np.frombuffer(data, dtype=np.float32, offset=_TILE_HEADER.size).reshape(h, w, 4)
    return x0, y0, rgba
