"""The render worker: takes tile tasks from the Redis stream, renders them, stores results.

Delivery is at-least-once. A worker stores a tile's result and only then acknowledges its
stream entry; results are keyed by tile index, so a tile rendered twice is stored once.
A worker that dies mid-tile leaves the entry pending under its name; its heartbeat key
expires and another worker's reaper claims the entry and renders it. A slow tile on a live
worker is never taken away, however long it runs.
"""
from __future__ import annotations

import logging
import os
import secrets
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import PurePosixPath

import redis
from tessera_renderer import SceneError, load_scene

from tessera import protocol
from tessera.protocol import TileTask

log = logging.getLogger("tessera.worker")

HEARTBEAT_TTL = 5.0        # seconds a worker counts as alive after its last heartbeat
BLOCK_MS = 1000            # how long one XREADGROUP waits for work
REAP_INTERVAL = 2.0        # seconds between looks for tiles held by dead workers
CLAIM_MIN_IDLE_MS = 1000   # two reapers do not both claim a tile claimed within this time
SCENE_CACHE_SIZE = 4

# Marks the job running on its first tile and says whether the tile still needs rendering.
# Returns the job's state before the call, "" if the job does not exist, or "stored" if
# this tile's result is already stored (a redelivery after a store whose ack was lost).
_BEGIN_TILE = """
local state = redis.call('HGET', KEYS[1], 'state')
if not state then return '' end
if state == 'done' or state == 'failed' or state == 'cancelled' then return state end
if redis.call('HEXISTS', KEYS[2], ARGV[1]) == 1 then return 'stored' end
if state == 'queued' then redis.call('HSET', KEYS[1], 'state', 'running') end
redis.call('HSETNX', KEYS[1], 'started_at', ARGV[2])
return state
"""

# Stores a tile result and, if it was the last one, marks the job done, in one step.
# Returns 1 if this call completed the job, 0 if not, -1 if the job is gone, cancelled or
# failed (the result is then dropped).
_STORE_TILE = """
local state = redis.call('HGET', KEYS[1], 'state')
if (not state) or state == 'failed' or state == 'cancelled' then return -1 end
if redis.call('HSETNX', KEYS[2], ARGV[1], ARGV[2]) == 1 then
  redis.call('HINCRBYFLOAT', KEYS[1], 'render_seconds', ARGV[3])
end
local stored = redis.call('HLEN', KEYS[2])
local total = tonumber(redis.call('HGET', KEYS[1], 'tiles_total'))
if state ~= 'done' and total and stored >= total then
  redis.call('HSET', KEYS[1], 'state', 'done', 'finished_at', ARGV[4])
  return 1
end
return 0
"""

# Fails a job unless it already reached a final state. Returns the state before the call.
_FAIL_JOB = """
local state = redis.call('HGET', KEYS[1], 'state')
if not state then return '' end
if state == 'queued' or state == 'running' then
  redis.call('HSET', KEYS[1], 'state', 'failed', 'error', ARGV[1], 'finished_at', ARGV[2])
end
return state
"""

# Removes a consumer from the group only if it holds no pending entries (DELCONSUMER
# would silently drop them). Returns 1 if removed.
_DROP_IDLE_CONSUMER = """
local pending = redis.call('XPENDING', KEYS[1], ARGV[1], '-', '+', 1, ARGV[2])
if #pending > 0 then return 0 end
redis.call('XGROUP', 'DELCONSUMER', KEYS[1], ARGV[1], ARGV[2])
return 1
"""


def default_worker_name() -> str:
    return f"{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(3)}"


def run_worker(redis_url: str, name: str | None = None, threads: int = 1,
               stop_event: threading.Event | None = None, *,
               heartbeat_ttl: float = HEARTBEAT_TTL) -> None:
    """Runs a worker until stop_event is set or SIGTERM/SIGINT arrives (when called from
    the main thread). A stop request lets the current tile finish; a second signal kills
    the process at once. `threads` is the renderer's thread count per tile."""
    worker = Worker(redis_url, name=name, threads=threads, heartbeat_ttl=heartbeat_ttl)
    stop = stop_event if stop_event is not None else threading.Event()
    restore = _install_signal_handlers(stop) if threading.current_thread() is threading.main_thread() else None
    try:
        worker.run(stop)
    finally:
        if restore:
            restore()


def _install_signal_handlers(stop: threading.Event):
    previous = {}

    def on_signal(signum, frame):
        if stop.is_set():
            return
        log.info("received %s: finishing the current tile, then exiting "
                 "(send it again to exit now)", signal.Signals(signum).name)
        stop.set()
        # A second signal takes the default action: the process ends immediately.
        signal.signal(signum, signal.SIG_DFL)

    for sig in (signal.SIGTERM, signal.SIGINT):
        previous[sig] = signal.signal(sig, on_signal)

    def restore():
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return restore


class Worker:
    def __init__(self, redis_url: str, name: str | None = None, threads: int = 1,
                 heartbeat_ttl: float = HEARTBEAT_TTL):
        self.name = name or default_worker_name()
        self.threads = threads
        self.heartbeat_ttl = heartbeat_ttl
        self.redis = redis.Redis.from_url(redis_url, socket_connect_timeout=5,
                                          socket_timeout=BLOCK_MS / 1000 + 10,
                                          health_check_interval=30)
        self._begin_tile = self.redis.register_script(_BEGIN_TILE)
        self._store_tile = self.redis.register_script(_STORE_TILE)
        self._fail_job = self.redis.register_script(_FAIL_JOB)
        self._drop_idle_consumer = self.redis.register_script(_DROP_IDLE_CONSUMER)
        self._scenes: OrderedDict[tuple[str, str], object] = OrderedDict()
        self._scene_paths: dict[tuple[str, str], str] = {}
        self._tmpdir: str | None = None
        self.tiles_rendered = 0

    # ----------------------------------------------------------------- main loop
    def run(self, stop: threading.Event) -> None:
        self._tmpdir = tempfile.mkdtemp(prefix="tessera-worker-")
        heartbeat_stop = threading.Event()
        heartbeat = threading.Thread(target=self._heartbeat_loop, args=(heartbeat_stop,),
                                     name="tessera-heartbeat", daemon=True)
        log.info("worker %s starting (renderer threads: %s)", self.name, self.threads)
        try:
            # Alive before joining the group: a consumer without a heartbeat is dead.
            self._wait_for_redis(stop, self._beat)
            heartbeat.start()
            self._wait_for_redis(stop, self._ensure_group)
            self._loop(stop)
        finally:
            heartbeat_stop.set()
            if heartbeat.is_alive():
                heartbeat.join(timeout=5)
            self._leave()
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            log.info("worker %s stopped after %d tiles", self.name, self.tiles_rendered)

    def _loop(self, stop: threading.Event) -> None:
        next_reap = 0.0
        read_backlog = True  # our own pending entries first (after a lost connection)
        redis_down = False
        while not stop.is_set():
            try:
                if time.monotonic() >= next_reap:
                    self._reap(stop)
                    next_reap = time.monotonic() + REAP_INTERVAL
                if stop.is_set():
                    break
                reply = self.redis.xreadgroup(
                    protocol.WORKER_GROUP, self.name,
                    {protocol.TILE_STREAM: "0" if read_backlog else ">"},
                    count=1, block=None if read_backlog else BLOCK_MS)
                entries = reply[0][1] if reply else []
                if read_backlog and not entries:
                    read_backlog = False
                for entry_id, fields in entries:
                    self._process(entry_id, fields)
                if redis_down:
                    log.info("redis is reachable again")
                    redis_down = False
            except redis.ResponseError as e:
                read_backlog = True
                if "NOGROUP" in str(e):  # the stream or group was deleted under us
                    self._wait_for_redis(stop, self._ensure_group)
                    continue
                # E.g. Redis out of memory: keep the tile pending and retry it later.
                log.error("redis refused a command (%s); retrying", e)
                stop.wait(1.0)
            except (redis.ConnectionError, redis.TimeoutError) as e:
                if not redis_down:
                    log.warning("lost redis (%s); retrying", e)
                    redis_down = True
                read_backlog = True
                stop.wait(1.0)

    def _wait_for_redis(self, stop: threading.Event, action) -> None:
        while not stop.is_set():
            try:
                action()
                return
            except (redis.ConnectionError, redis.TimeoutError) as e:
                log.warning("cannot reach redis (%s); retrying", e)
                stop.wait(1.0)

    def _ensure_group(self) -> None:
        try:
            self.redis.xgroup_create(protocol.TILE_STREAM, protocol.WORKER_GROUP,
                                     id="0", mkstream=True)
        except redis.ResponseError as e:
            if "BUSYGROUP" not in str(e):
                raise

    # ----------------------------------------------------------------- one tile
    def _process(self, entry_id: bytes, fields: dict | None) -> None:
        """Handles one stream entry; acknowledges it unless Redis itself fails."""
        if not fields:  # the entry was deleted from the stream while pending
            self._ack(entry_id)
            return
        try:
            task = TileTask.from_fields(fields)
        except ValueError as e:  # includes pydantic's ValidationError
            log.error("dropping malformed stream entry %s: %s", entry_id, e)
            self._ack(entry_id)
            return

        job_key = protocol.job_key(task.job_id)
        tiles_key = protocol.job_tiles_key(task.job_id)
        index = str(task.tile.index)
        before = _text(self._begin_tile(keys=[job_key, tiles_key], args=[index, time.time()]))
        if before not in ("queued", "running"):
            log.debug("skipping tile %s of job %s (%s)", index, task.job_id, before or "no such job")
            self._ack(entry_id)
            return

        try:
            scene = self._scene(task)
            settings, rect = task.settings, task.tile
            started = time.perf_counter()
            rgba = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height,
                                     width=settings.width, height=settings.height,
                                     spp=settings.spp, seed=settings.seed,
                                     max_depth=settings.max_depth, threads=self.threads)
            seconds = time.perf_counter() - started
            data = protocol.encode_tile(rect, rgba)
        except redis.RedisError:
            raise
        except Exception as e:  # SceneError, MemoryError, a renderer bug: fail the job
            message = _describe(e, task)
            log.error("job %s failed: %s", task.job_id, message)
            self._fail_job(keys=[job_key], args=[message, time.time()])
            self._ack(entry_id)
            return

        completed = self._store_tile(keys=[job_key, tiles_key],
                                     args=[index, data, repr(seconds), time.time()])
        self._ack(entry_id)
        self.tiles_rendered += 1
        log.debug("job %s tile %s rendered in %.3f s", task.job_id, index, seconds)
        if completed == 1:
            log.info("job %s done", task.job_id)

    def _ack(self, entry_id: bytes) -> None:
        # Entries are removed once acknowledged, so the stream holds only open work.
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.xack(protocol.TILE_STREAM, protocol.WORKER_GROUP, entry_id)
            pipe.xdel(protocol.TILE_STREAM, entry_id)
            pipe.execute()

    def _scene(self, task: TileTask):
        """The loaded scene for a task, from a small LRU cache keyed by content hash and
        file suffix (the suffix tells USD the format)."""
        suffix = PurePosixPath(task.scene_name).suffix.lower()
        key = (task.scene_hash, suffix)
        if key in self._scenes:
            self._scenes.move_to_end(key)
            return self._scenes[key]
        data = self.redis.hget(protocol.scene_key(task.scene_hash), "data")
        if data is None:
            raise SceneError(f"scene {task.scene_hash} is missing from the store")
        path = os.path.join(self._tmpdir, f"{task.scene_hash}{suffix}")
        with open(path, "wb") as f:
            f.write(data)
        del data
        try:
            scene = load_scene(path)
        except BaseException:
            os.unlink(path)
            raise
        for warning in getattr(scene, "warnings", []):
            log.debug("scene %s: %s", task.scene_name, warning)
        self._scenes[key] = scene
        self._scene_paths[key] = path
        while len(self._scenes) > SCENE_CACHE_SIZE:
            old, _ = self._scenes.popitem(last=False)
            os.unlink(self._scene_paths.pop(old))
        return scene

    # ----------------------------------------------------------------- liveness
    def _beat(self) -> None:
        self.redis.set(protocol.worker_key(self.name), f"{socket.gethostname()} pid {os.getpid()}",
                       px=int(self.heartbeat_ttl * 1000))

    def _heartbeat_loop(self, stop: threading.Event) -> None:
        interval = max(0.1, self.heartbeat_ttl / 5)
        while not stop.wait(interval):
            try:
                self._beat()
            except redis.RedisError as e:
                log.debug("heartbeat failed: %s", e)

    def _reap(self, stop: threading.Event) -> None:
        """Claims and renders the tiles held by consumers whose heartbeat has expired,
        then removes those consumers from the group."""
        try:
            consumers = self.redis.xinfo_consumers(protocol.TILE_STREAM, protocol.WORKER_GROUP)
        except redis.ResponseError as e:
            if "NOGROUP" in str(e) or "no such key" in str(e):
                return
            raise
        for consumer in consumers:
            dead = _text(consumer["name"])
            if dead == self.name or self.redis.exists(protocol.worker_key(dead)):
                continue
            if int(consumer.get("pending", 0)) > 0:
                log.info("worker %s is gone; taking over its %s pending tile(s)",
                         dead, consumer["pending"])
                for pending in self.redis.xpending_range(
                        protocol.TILE_STREAM, protocol.WORKER_GROUP, min="-", max="+",
                        count=100, consumername=dead):
                    if stop.is_set():
                        return
                    # One at a time, so that a tile is not held while others render.
                    claimed = self.redis.xclaim(protocol.TILE_STREAM, protocol.WORKER_GROUP,
                                                self.name, CLAIM_MIN_IDLE_MS,
                                                [pending["message_id"]])
                    for entry_id, fields in claimed:
                        self._process(entry_id, fields)
            if self._drop_idle_consumer(keys=[protocol.TILE_STREAM],
                                        args=[protocol.WORKER_GROUP, dead]):
                log.info("removed dead worker %s from the group", dead)

    def _leave(self) -> None:
        """On a clean exit: stop counting as alive and leave the group if nothing is held."""
        try:
            self.redis.delete(protocol.worker_key(self.name))
            self._drop_idle_consumer(keys=[protocol.TILE_STREAM],
                                     args=[protocol.WORKER_GROUP, self.name])
        except redis.RedisError as e:
            log.debug("could not leave cleanly: %s", e)


def _describe(error: BaseException, task: TileTask) -> str:
    if isinstance(error, SceneError):
        return f"cannot load scene {task.scene_name!r}: {error}"
    if isinstance(error, MemoryError):
        return f"out of memory rendering tile {task.tile.index} of {task.scene_name!r}"
    return (f"rendering tile {task.tile.index} of {task.scene_name!r} failed: "
            f"{type(error).__name__}: {error}")


def _text(value) -> str:
    if value is None:
        return ""
    return value.decode() if isinstance(value, bytes) else str(value)
