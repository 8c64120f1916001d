"""The service's Redis operations on scenes, jobs, workers and their results (keys, fields
and the state machine: tessera_queue.redis_schema; messages: tessera_base.protocol)."""
from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

import redis

from tessera_base import protocol
from tessera_queue import tasks as queue_tasks
from tessera_queue import redis_schema as rdb
from tessera_queue.data_store import DataStore, default_root
from tessera_base.protocol import FINAL_STATES, JobSpec


@dataclass
class Job:
    spec: JobSpec
    state: str
    tiles_total: int
    tiles_done: int
    passes_done: int
    created_at: float
    started_at: float | None
    finished_at: float | None
    render_seconds: float
    warnings: list[str]
    error: str | None
    owner: str | None = None
    # A done noise-target job's reached noise, once measured (remember_reached_error):
    # the number as text, "none" when the image has no noise estimate; None: not yet.
    reached_error: str | None = None
    brightest_light: str | None = None  # what a black image's warning names
    sequence: str | None = None         # the frame range it is a frame of

    @property
    def final(self) -> bool:
        return self.state in FINAL_STATES


@dataclass
class WorkerInfo:
    name: str
    host: str
    pid: int
    started_at: float
    beat_at: float
    current: str
    tiles_done: int
    failures: int
    disabled: bool = False


class JobStore:
    def __init__(self, client: redis.Redis, *, retention: float = 7 * 86400,
                 scene_retention: float = 7 * 86400, data_dir: str | None = None):
        self.redis = client
        self.retention = retention
        self.scene_retention = scene_retention
        self.scripts = rdb.Scripts(client)
        self.data = DataStore(data_dir or default_root(), client)

    @classmethod
    def from_url(cls, url: str, **kwargs) -> "JobStore":
        return cls(redis.Redis.from_url(url, socket_connect_timeout=5, socket_timeout=30,
                                        health_check_interval=30), **kwargs)

    def ping(self) -> bool:
        try:
            return bool(self.redis.ping())
        except redis.RedisError:
            return False

    # ------------------------------------------------------------------ scenes
    def put_scene(self, scene_hash: str, name: str, source: bytes | str | os.PathLike) -> None:
        """Stores a scene (bytes, or a file) once per content hash, its SHA-256: the bytes
        in the data store, which the scene hash holds; every use extends its retention."""
        key = rdb.scene_key(scene_hash)
        size = len(source) if isinstance(source, bytes) else os.path.getsize(source)
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hsetnx(key, "name", name)
            pipe.hset(key, "size", size)
            pipe.hdel(key, "data")  # the bytes themselves, where farms before the data store kept them
            self.data.hold(pipe, scene_hash, size, key)  # index first: see data_store
            pipe.execute()
        self.touch_scene(scene_hash)
        if isinstance(source, bytes):
            self.data.write_bytes(scene_hash, source)
        else:
            self.data.write_file(scene_hash, source)

    def touch_scene(self, scene_hash: str) -> bool:
        """Extends a stored scene's retention (a scene a job holds does not expire at all);
        False if it is not stored."""
        ttl = int(self.scene_retention) if self.scene_retention > 0 else 0
        return bool(self.scripts.touch_scene(
            keys=[rdb.scene_key(scene_hash), rdb.scene_jobs_key(scene_hash)], args=[ttl]))

    def preflight(self, scene_hash: str, suffix: str, limits: str,
                  variants: Sequence[str] = ()) -> dict | None:
        """The remembered pre-flight of a scene (these bytes under this `suffix`, composed
        with `variants`): its SceneInfo fields, or {"error": why} for a refusal, when it was
        reached under the same `limits` (under others it is forgotten: a refused scene may
        pass now, a passed one may be over a lowered limit)."""
        raw = self.redis.get(rdb.preflight_key(scene_hash, suffix, variants))
        if not raw:
            return None
        value = json.loads(raw)
        if value.pop("limits", None) != limits:
            return None
        return value

    def remember_preflight(self, scene_hash: str, suffix: str, info: dict, limits: str,
                           variants: Sequence[str] = ()) -> None:
        ttl = int(self.scene_retention) if self.scene_retention > 0 else None
        self.redis.set(rdb.preflight_key(scene_hash, suffix, variants),
                       json.dumps({**info, "limits": limits}), ex=ttl)

    def remember_rejection(self, scene_hash: str, suffix: str, error: str, limits: str,
                           variants: Sequence[str] = ()) -> None:
        """Remembers for the scene retention that this file was refused, so that uploading
        it again is refused at once, without another inspection."""
        self.remember_preflight(scene_hash, suffix, {"error": error}, limits, variants)

    def count_inspection(self, rejected: bool) -> None:
        with self.redis.pipeline(transaction=False) as pipe:
            pipe.hincrby(rdb.STATS, "inspections", 1)
            if rejected:
                pipe.hincrby(rdb.STATS, "inspections_rejected", 1)
            pipe.execute()

    # ------------------------------------------------------------------ jobs
    def create_job(self, spec: JobSpec, warnings: list[str], owner: str | None = None,
                   brightest_light: str | None = None, sequence: str | None = None,
                   note: str | None = None) -> int:
        """Creates the job (owned by the API user `owner`; None: by nobody, so that only
        admins see it), its queue with the first pass
        of every tile, and its place in the schedule, in one transaction: workers never see
        a task whose job does not exist, nor a job with part of its tiles."""
        tasks = queue_tasks.job_tasks(spec)
        now = time.time()
        queue = rdb.job_queue_key(spec.job_id)
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hset(rdb.job_key(spec.job_id), mapping={
                "spec": spec.model_dump_json(),
                "scene_hash": spec.scene_hash,
                "state": "queued",
                "priority": spec.priority,
                "created_at": repr(now),
                # The grid's tiles, not the first tasks: a scene-pass job starts with one
                # scene task, and lockstep barriers count tile passes by this.
                "tiles_total": len(protocol.job_tiles(spec.settings)),
                "tiles_done": 0,
                "passes_done": 0,
                "render_seconds": 0,
                "retention": int(self.retention),
                "warnings": json.dumps(warnings),
                **({"owner": owner} if owner is not None else {}),
                **({"brightest_light": brightest_light} if brightest_light else {}),
                **({"sequence": sequence} if sequence else {}),
            })
            pipe.zadd(rdb.JOB_INDEX, {spec.job_id: now})
            if owner is not None:
                pipe.zadd(rdb.user_jobs_key(owner), {spec.job_id: now})
            pipe.sadd(rdb.ACTIVE, spec.job_id)
            pipe.xgroup_create(queue, rdb.WORKER_GROUP, id="0", mkstream=True)
            for task in tasks:
                pipe.xadd(queue, task.to_fields())
            pipe.rpush(rdb.job_log_key(spec.job_id),
                       f"{now!r} job queued: {len(tasks)} tiles, priority {spec.priority}")
            if note:  # why it exists (a retry of which job), before any worker's line
                pipe.rpush(rdb.job_log_key(spec.job_id), f"{now!r} {note}")
            for w in warnings:
                pipe.rpush(rdb.job_log_key(spec.job_id), f"{now!r} warning: {w}")
            if spec.settings.auto_pilot:
                pipe.rpush(rdb.job_log_key(spec.job_id), f"{now!r} integrator {spec.settings.integrator} chosen "
                                                         f"by the client's auto pilot: {spec.settings.auto_pilot}")
            pipe.xadd(rdb.job_events_key(spec.job_id),
                      rdb.JobEvent(type="state", state="queued").to_fields())
            self.scripts.admit_job(keys=rdb.job_script_keys(spec.job_id, spec.scene_hash),
                                   args=[spec.job_id], client=pipe)
            pipe.execute()
        return len(tasks)

    def create_sequence(self, sequence_id: str, frames: list[tuple[int, str]], scene_name: str,
                        warnings: list[str], owner: str | None = None) -> None:
        """Records a frame range whose frames' jobs exist already (create_job each)."""
        key = rdb.sequence_key(sequence_id)
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hset(key, mapping={"frames": json.dumps(frames), "scene_name": scene_name,
                                    "created_at": repr(time.time()), "warnings": json.dumps(warnings),
                                    **({"owner": owner} if owner is not None else {})})
            if self.retention > 0:
                pipe.expire(key, int(self.retention * rdb.SEQUENCE_TTL_FACTOR))
            pipe.execute()

    def sequence(self, sequence_id: str) -> dict | None:
        """A frame range (see redis_schema.sequence_key) with its frames' jobs:
        {frames: [(frame, job id, Job or None once expired)], scene_name, owner, created_at,
        warnings}; None if there is none (or every frame's job has expired: then it is
        forgotten too). Reading it keeps it as long again."""
        key = rdb.sequence_key(sequence_id)
        fields = self.redis.hgetall(key)
        if not fields:
            return None
        f = {k.decode(): v.decode() for k, v in fields.items()}
        frames = json.loads(f["frames"])
        with self.redis.pipeline(transaction=False) as pipe:
            for _, job_id in frames:
                pipe.hgetall(rdb.job_key(job_id))
            rows = pipe.execute()
        if not any(rows):
            self.redis.delete(key)
            return None
        if self.retention > 0:
            self.redis.expire(key, int(self.retention * rdb.SEQUENCE_TTL_FACTOR))
        return {"frames": [(frame, job_id, _job(row) if row else None) for (frame, job_id), row in zip(frames, rows)],
                "scene_name": f["scene_name"], "owner": f.get("owner"), "created_at": float(f["created_at"]),
                "warnings": json.loads(f.get("warnings") or "[]")}

    def get(self, job_id: str) -> Job | None:
        fields = self.redis.hgetall(rdb.job_key(job_id))
        return _job(fields) if fields else None

    def owner(self, job_id: str) -> str | None:
        raw = self.redis.hget(rdb.job_key(job_id), "owner")
        return raw.decode() if raw is not None else None

    def list(self, state: str | None = None, limit: int = 100, offset: int = 0,
             owner: str | None = None, name: str | None = None) -> list[Job]:
        """Jobs newest first, optionally only those in `state`, only those of `owner`
        (None: everyone's), only those whose scene name contains `name` (any case). Drops
        index entries of jobs that have expired."""
        needle = name.casefold() if name else None
        index = rdb.user_jobs_key(owner) if owner is not None else rdb.JOB_INDEX
        out: list[Job] = []
        start = 0
        batch = 200
        while len(out) < offset + limit:
            ids = self.redis.zrevrange(index, start, start + batch - 1)
            if not ids:
                break
            start += batch
            with self.redis.pipeline(transaction=False) as pipe:
                for job_id in ids:
                    pipe.hgetall(rdb.job_key(job_id.decode()))
                rows = pipe.execute()
            gone = [job_id for job_id, fields in zip(ids, rows) if not fields]
            if gone:
                self.redis.zrem(index, *gone)
                start -= len(gone)
            for fields in rows:
                if fields:
                    job = _job(fields)
                    if ((state is None or job.state == state)
                            and (needle is None or needle in job.spec.scene_name.casefold())):
                        out.append(job)
        return out[offset:offset + limit]

    def _update_json_field(self, key: str, field: str, change, also=None) -> bool:
        """Rewrites the JSON list in hash `key`'s `field` to change(value) atomically (WATCH,
        retried when another writer came first); `also(pipe)` adds commands to the same
        transaction. False, and nothing written, when the field is gone or change gives None."""
        with self.redis.pipeline(transaction=True) as pipe:
            while True:
                try:
                    pipe.watch(key)
                    raw = pipe.hget(key, field)
                    if raw is None:
                        return False
                    value = change(json.loads(raw))
                    if value is None:
                        return False
                    pipe.multi()
                    pipe.hset(key, field, json.dumps(value))
                    if also is not None:
                        also(pipe)
                    pipe.execute()
                    return True
                except redis.WatchError:
                    continue

    def replace_frame(self, sequence_id: str, old_job: str, new_job: str) -> bool:
        """Makes `new_job` the frame range's job for the frame `old_job` rendered (a retry);
        False if the record is gone or does not list `old_job`."""
        def change(frames):
            if not any(job == old_job for _, job in frames):
                return None
            return [[f, new_job if job == old_job else job] for f, job in frames]
        return self._update_json_field(rdb.sequence_key(sequence_id), "frames", change)

    def forget_sequence(self, sequence_id: str) -> None:
        self.redis.delete(rdb.sequence_key(sequence_id))

    def add_log(self, job_id: str, text: str) -> None:
        with self.redis.pipeline(transaction=False) as pipe:
            pipe.rpush(rdb.job_log_key(job_id), f"{time.time()!r} {text}")
            pipe.ltrim(rdb.job_log_key(job_id), -rdb.LOG_MAXLEN, -1)
            pipe.execute()

    def purge(self, job_id: str, owner: str | None) -> None:
        """Removes a final job and everything it keeps (redis_schema.job_keys) at once,
        rather than at the end of its retention."""
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.delete(*rdb.job_keys(job_id))
            pipe.zrem(rdb.JOB_INDEX, job_id)
            pipe.srem(rdb.ACTIVE, job_id)
            if owner is not None:
                pipe.zrem(rdb.user_jobs_key(owner), job_id)
            pipe.execute()

    def _keys(self, job_id: str) -> list[str]:
        scene_hash = self.redis.hget(rdb.job_key(job_id), "scene_hash")
        return rdb.job_script_keys(job_id, scene_hash.decode() if scene_hash else "")

    def cancel(self, job_id: str) -> bool:
        """Cancels the job unless it is already final. False if there is no such job."""
        return self.scripts.cancel_job(keys=self._keys(job_id), args=[job_id, repr(time.time())]) != b""

    def pause(self, job_id: str) -> bool:
        return self.scripts.pause_job(keys=self._keys(job_id), args=[job_id, repr(time.time())]) != b""

    def resume(self, job_id: str) -> bool:
        return self.scripts.resume_job(keys=self._keys(job_id), args=[job_id, repr(time.time())]) != b""

    def set_priority(self, job_id: str, priority: int) -> bool:
        """Changes the priority of a job not yet final (a final one is left as it is).
        False if there is no such job."""
        return self.scripts.set_priority(keys=self._keys(job_id),
                                         args=[job_id, repr(time.time()), priority]) != b""

    def tiles(self, job_id: str) -> dict[bytes, bytes]:
        return self.redis.hgetall(rdb.job_tiles_key(job_id))

    def splats(self, job_id: str) -> dict[bytes, bytes]:
        """The job's splat sums (redis_schema.job_splats_key), for merging."""
        return self.redis.hgetall(rdb.job_splats_key(job_id))

    def remember_reached_error(self, job_id: str, value: float | None) -> None:
        """Keeps a done job's measured noise in its hash, so it is merged once; a job that
        expired or was deleted meanwhile is not brought back as a bare hash."""
        self.redis.eval("if redis.call('exists', KEYS[1]) == 1 then "
                        "return redis.call('hset', KEYS[1], ARGV[1], ARGV[2]) end return 0",
                        1, rdb.job_key(job_id), "reached_error", "none" if value is None else repr(value))

    def add_warning(self, job_id: str, warning: str) -> bool:
        """Adds a warning found once the job's image exists (a black image) to its
        warnings and its log, once; False when it was there already or the job is gone."""
        return self._update_json_field(
            rdb.job_key(job_id), "warnings",
            lambda warnings: None if warning in warnings else [*warnings, warning],
            also=lambda pipe: pipe.rpush(rdb.job_log_key(job_id), f"{time.time()!r} warning: {warning}"))

    def task_sources(self, job_id: str) -> dict:
        """What the per-tile table of a job (tasks_view) is folded from, read at once:
        events (the stream, oldest first: [(id, fields)]), failures (the failures hash),
        open (the queue's entries: [(entry id, fields)], queued or being rendered) and
        pending (entry id -> (consumer, ms since delivered, deliveries) of those being
        rendered)."""
        queue = rdb.job_queue_key(job_id)
        with self.redis.pipeline(transaction=False) as pipe:
            pipe.xrange(rdb.job_events_key(job_id))
            pipe.hgetall(rdb.job_failures_key(job_id))
            pipe.xrange(queue)
            events, failures, open_entries = pipe.execute()
        try:
            rows = self.redis.xpending_range(queue, rdb.WORKER_GROUP, min="-", max="+",
                                             count=max(1, len(open_entries)))
        except redis.ResponseError as e:
            if "NOGROUP" not in str(e):  # (a refusal, NOPERM say, is no empty queue)
                raise
            rows = []  # no queue (a final job) or no group: nothing in flight
        pending = {r["message_id"]: (r["consumer"].decode(), int(r["time_since_delivered"]),
                                     int(r["times_delivered"])) for r in rows}
        return {"events": events, "failures": {k.decode(): int(v) for k, v in failures.items()},
                "open": open_entries, "pending": pending}

    def log(self, job_id: str) -> list[str]:
        return [line.decode(errors="replace")
                for line in self.redis.lrange(rdb.job_log_key(job_id), 0, -1)]

    def cached_image(self, job_id: str, fmt: str) -> bytes | None:
        return self.redis.get(rdb.job_image_key(job_id, fmt))

    def cache_image(self, job_id: str, fmt: str, data: bytes) -> None:
        """Caches a done job's image for as long as the job itself is kept."""
        ttl = self.redis.pttl(rdb.job_key(job_id))
        key = rdb.job_image_key(job_id, fmt)
        if ttl and ttl > 0:
            self.redis.set(key, data, px=ttl)
        else:
            self.redis.set(key, data)

    # ------------------------------------------------------------------ farm state
    def workers(self) -> list[WorkerInfo]:
        names = sorted(n.decode() for n in self.redis.smembers(rdb.WORKERS))
        with self.redis.pipeline(transaction=False) as pipe:
            for name in names:
                pipe.hgetall(rdb.worker_key(name))
            rows = pipe.execute()
        out = []
        for name, fields in zip(names, rows):
            if not fields:
                continue  # its heartbeat expired: the reapers take care of it
            f = {k.decode(): v.decode() for k, v in fields.items()}
            out.append(WorkerInfo(name=name, host=f.get("host", ""), pid=int(f.get("pid", 0)),
                                  started_at=float(f.get("started_at", 0)),
                                  beat_at=float(f.get("beat_at", 0)),
                                  current=f.get("current", ""),
                                  tiles_done=int(f.get("tiles_done", 0)),
                                  failures=int(f.get("failures", 0)),
                                  disabled=bool(f.get("disabled"))))
        return out

    def set_worker_disabled(self, name: str, disabled: bool) -> bool:
        """Marks a live worker disabled (it takes no new task; the one it renders it
        finishes) or enabled again; False if no live worker has that name (a dead one's
        hash is not brought back)."""
        script = ("if redis.call('exists', KEYS[1]) == 0 then return 0 end "
                  + ("redis.call('hset', KEYS[1], 'disabled', '1') " if disabled
                     else "redis.call('hdel', KEYS[1], 'disabled') ") + "return 1")
        return bool(self.redis.eval(script, 1, rdb.worker_key(name)))

    def clear_blocklist(self, name: str) -> list[str]:
        """Takes the worker off the blocklists of every job not yet final, and forgets its
        failures there (else its next failure blocklists it again at once); returns the
        ids of the jobs it was blocklisted for."""
        ids = sorted(j.decode() for j in self.redis.smembers(rdb.ACTIVE))
        with self.redis.pipeline(transaction=False) as pipe:
            for job_id in ids:
                pipe.srem(rdb.job_blocklist_key(job_id), name)
                pipe.hdel(rdb.job_failures_key(job_id), f"worker:{name}")
            rows = pipe.execute()
        return [job_id for job_id, removed in zip(ids, rows[0::2]) if removed]

    def seconds_since_progress(self) -> float | None:
        """Seconds since the newest event of any queued or running job (a tile pass stored,
        a state change, a failure), or None when no such job exists: how long the queue has
        not moved while there is work in it."""
        ids = [j.decode() for j in self.redis.smembers(rdb.ACTIVE)]
        with self.redis.pipeline(transaction=False) as pipe:
            for job_id in ids:
                pipe.hget(rdb.job_key(job_id), "state")
                pipe.xrevrange(rdb.job_events_key(job_id), count=1)
            rows = pipe.execute()
        newest = None
        for state, events in zip(rows[0::2], rows[1::2]):
            if state is None or state.decode() not in ("queued", "running"):
                continue
            ms = int(events[0][0].decode().split("-")[0]) if events else 0
            newest = ms if newest is None else max(newest, ms)
        if newest is None:
            return None
        # This host's clock against the Redis host's (event ids are its milliseconds): the
        # API's Redis user may not run TIME (the ACL grants data commands only; asking for
        # it made /healthz answer 500 whenever there was work). Hosts kept by NTP differ by
        # far less than the stall threshold (minutes).
        return max(0.0, time.time() - newest / 1000.0)

    def stats(self) -> dict[str, float]:
        return {k.decode(): float(v) for k, v in self.redis.hgetall(rdb.STATS).items()}

    def queue_depths(self) -> dict[int, int]:
        """Open tile passes (queued or being rendered) per priority, over active jobs."""
        ids = [j.decode() for j in self.redis.smembers(rdb.ACTIVE)]
        with self.redis.pipeline(transaction=False) as pipe:
            for job_id in ids:
                pipe.hget(rdb.job_key(job_id), "priority")
                pipe.xlen(rdb.job_queue_key(job_id))
            rows = pipe.execute()
        depths = {p: 0 for p in range(protocol.MIN_PRIORITY, protocol.MAX_PRIORITY + 1)}
        for priority, length in zip(rows[::2], rows[1::2]):
            if priority is not None:
                depths[int(priority)] = depths.get(int(priority), 0) + int(length)
        return depths


def _job(fields: dict[bytes, bytes]) -> Job:
    f = {k.decode(): v.decode() for k, v in fields.items()}
    spec = JobSpec.model_validate_json(f["spec"])
    if f.get("priority") and int(f["priority"]) != spec.priority:  # changed since submission
        spec = spec.model_copy(update={"priority": int(f["priority"])})
    return Job(
        spec=spec,
        state=f["state"],
        tiles_total=int(f["tiles_total"]),
        tiles_done=int(f.get("tiles_done") or 0),
        passes_done=int(f.get("passes_done") or 0),
        created_at=float(f["created_at"]),
        started_at=_float(f.get("started_at")),
        finished_at=_float(f.get("finished_at")),
        render_seconds=float(f.get("render_seconds") or 0.0),
        warnings=json.loads(f.get("warnings") or "[]"),
        error=f.get("error") or None,
        owner=f.get("owner"),
        reached_error=f.get("reached_error"),
        brightest_light=f.get("brightest_light") or None,
        sequence=f.get("sequence") or None,
    )


def _float(value: str | None) -> float | None:
    return float(value) if value else None
