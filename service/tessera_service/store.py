"""The service's Redis operations on scenes, jobs and their results (key layout and
message schema: tessera.protocol)."""
from __future__ import annotations

import json
import time
from dataclasses import dataclass

import redis

from tessera import protocol
from tessera.protocol import FINAL_STATES, JobSpec, TileTask

# Cancels a job unless it already reached a final state. Returns the state before the call
# ("" if there is no such job).
_CANCEL_JOB = """
local state = redis.call('HGET', KEYS[1], 'state')
if not state then return '' end
if state == 'queued' or state == 'running' then
  redis.call('HSET', KEYS[1], 'state', 'cancelled', 'finished_at', ARGV[1])
end
return state
"""


@dataclass
class Job:
    spec: JobSpec
    state: str
    tiles_total: int
    tiles_done: int
    created_at: float
    started_at: float | None
    finished_at: float | None
    render_seconds: float
    warnings: list[str]
    error: str | None

    @property
    def final(self) -> bool:
        return self.state in FINAL_STATES


class JobStore:
    def __init__(self, client: redis.Redis):
        self.redis = client
        self._cancel = client.register_script(_CANCEL_JOB)

    @classmethod
    def from_url(cls, url: str) -> "JobStore":
        return cls(redis.Redis.from_url(url, socket_connect_timeout=5, socket_timeout=30,
                                        health_check_interval=30))

    def ping(self) -> bool:
        try:
            return bool(self.redis.ping())
        except redis.RedisError:
            return False

    def ensure_group(self) -> None:
        """Creates the stream and the workers' group, so that tasks queued before any
        worker starts are delivered."""
        try:
            self.redis.xgroup_create(protocol.TILE_STREAM, protocol.WORKER_GROUP,
                                     id="0", mkstream=True)
        except redis.ResponseError as e:
            if "BUSYGROUP" not in str(e):
                raise

    def put_scene(self, scene_hash: str, name: str, data: bytes) -> None:
        """Stores a scene once per content hash."""
        key = protocol.scene_key(scene_hash)
        if self.redis.hexists(key, "data"):
            return
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hsetnx(key, "name", name)
            pipe.hsetnx(key, "data", data)
            pipe.execute()

    def create_job(self, spec: JobSpec, warnings: list[str]) -> int:
        """Creates the job and queues one task per tile, in one transaction: workers never
        see a task whose job does not exist, nor a job with part of its tiles."""
        self.ensure_group()
        s = spec.settings
        grid = protocol.tile_grid(s.width, s.height, s.tile_size)
        now = time.time()
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hset(protocol.job_key(spec.job_id), mapping={
                "spec": spec.model_dump_json(),
                "state": "queued",
                "created_at": repr(now),
                "tiles_total": len(grid),
                "render_seconds": 0,
                "warnings": json.dumps(warnings),
            })
            pipe.zadd(protocol.JOB_INDEX, {spec.job_id: now})
            for rect in grid:
                task = TileTask(job_id=spec.job_id, scene_hash=spec.scene_hash,
                                scene_name=spec.scene_name, settings=s, tile=rect)
                pipe.xadd(protocol.TILE_STREAM, task.to_fields())
            pipe.execute()
        return len(grid)

    def get(self, job_id: str) -> Job | None:
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hgetall(protocol.job_key(job_id))
            pipe.hlen(protocol.job_tiles_key(job_id))
            fields, tiles_done = pipe.execute()
        if not fields:
            return None
        f = {k.decode(): v.decode() for k, v in fields.items()}
        return Job(
            spec=JobSpec.model_validate_json(f["spec"]),
            state=f["state"],
            tiles_total=int(f["tiles_total"]),
            tiles_done=int(tiles_done),
            created_at=float(f["created_at"]),
            started_at=_float(f.get("started_at")),
            finished_at=_float(f.get("finished_at")),
            render_seconds=float(f.get("render_seconds") or 0.0),
            warnings=json.loads(f.get("warnings") or "[]"),
            error=f.get("error") or None,
        )

    def cancel(self, job_id: str) -> bool:
        """Cancels the job unless it is already final. False if there is no such job."""
        return self._cancel(keys=[protocol.job_key(job_id)], args=[repr(time.time())]) != b""

    def tiles(self, job_id: str) -> dict[bytes, bytes]:
        return self.redis.hgetall(protocol.job_tiles_key(job_id))

    def cached_image(self, job_id: str, fmt: str) -> bytes | None:
        return self.redis.get(protocol.job_image_key(job_id, fmt))

    def cache_images(self, job_id: str, exr: bytes, png: bytes) -> None:
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.set(protocol.job_image_key(job_id, "exr"), exr)
            pipe.set(protocol.job_image_key(job_id, "png"), png)
            pipe.execute()


def _float(value: str | None) -> float | None:
    return float(value) if value else None
