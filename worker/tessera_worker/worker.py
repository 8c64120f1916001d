"""The render worker: takes tile tasks from the jobs' Redis streams, renders them in a
child process, stores the results.

Scheduling: every open job has its own stream; the worker asks one Lua script for the next
entry, which picks the highest-priority job and, among equal priorities, the job served
least (see rdb.READY). Paused, cancelled and blocklisted jobs are skipped there.

Delivery is at-least-once. A worker stores a pass's result and only then acknowledges its
entry; results are keyed by (tile, pass) and written with HSETNX, so a pass rendered twice
is stored once. A worker that dies mid-tile leaves the entry pending under its name; its
heartbeat expires and another worker's reaper claims the entry. A slow tile on a live
worker is never taken away.

Crash isolation: the renderer runs in a child process (render_child.py) with an
address-space limit and a per-tile time limit. A crash there fails that attempt only: the
tile is queued again, and after max_attempts failures the job fails naming the tile and
the error (the task goes to the dead-letter stream). A worker that fails one job
BLOCKLIST_AFTER times stops taking its tiles. Exceeding the memory or time limit, or a
scene that does not load, fails the job at once: those would fail the same way anywhere.
"""
from __future__ import annotations

import fnmatch
import hashlib
import logging
import os
import secrets
import shutil
import signal
import socket
import threading
import time

import redis

from tessera_base import protocol
from tessera_queue import redis_schema as rdb
from tessera_queue.data_store import DataStore, default_root
from tessera_base.process import private_tempdir, remove_orphaned_tempdirs
from tessera_queue.tasks import TileTask

from .child import Abandoned, RenderChild, RenderFailed
from .liveness import CLAIM_MIN_IDLE_MS, REAP_INTERVAL, Liveness  # noqa: F401 (the tests read CLAIM_MIN_IDLE_MS here)
from .passes import PassPolicy
from .redis_values import out_of_memory as _out_of_memory, text as _text, to_float as _float
from .results import ResultStore
from .scene_cache import SceneCache
from .settings import WorkerSettings
from .stop_grace import HandBack, StopGrace

log = logging.getLogger("tessera.worker")

IDLE_WAIT = 1.0            # longest wait for a wake-up token when there is no work
SCENE_TASK = -1            # a fault rule's target "#scene": scene-wide tasks, not tiles


def default_worker_name() -> str:
    return f"{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(3)}"


def run_worker(redis_url: str | None = None, name: str | None = None, threads: int | None = None,
               stop_event: threading.Event | None = None, *,
               heartbeat_ttl: float | None = None, settings: WorkerSettings | None = None) -> None:
    """Runs a worker until stop_event is set or SIGTERM/SIGINT arrives (when called from
    the main thread). A stop request lets the current tile finish, for up to
    settings.stop_grace seconds (then the tile is handed back to the queue: stop_grace.py);
    a second signal kills the process at once. Arguments given here override `settings` (default: from the
    environment)."""
    settings = settings or WorkerSettings()
    overrides = {k: v for k, v in dict(redis_url=redis_url, threads=threads,
                                       heartbeat_ttl=heartbeat_ttl).items() if v is not None}
    settings = settings.model_copy(update=overrides)
    worker = Worker(settings, name=name)
    problem = worker.data.unusable()
    if problem is not None:  # every scene it took would fail: say so once, at start
        log.critical("refusing to start: %s", problem)
        raise SystemExit(f"tessera worker: {problem}")
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


class Worker(SceneCache, ResultStore, PassPolicy, Liveness):
    """The Redis loop and one task's handling; its other roles are the mixins' (scene
    cache, result storage, pass policy, liveness), each in its own module."""

    def __init__(self, settings: WorkerSettings, name: str | None = None):
        self.settings = settings
        self.name = name or default_worker_name()
        self.threads = settings.threads
        self.heartbeat_ttl = settings.heartbeat_ttl
        self.redis = redis.Redis.from_url(settings.redis_url, socket_connect_timeout=5,
                                          socket_timeout=30, health_check_interval=30)
        self.scripts = rdb.Scripts(self.redis)
        self.data = DataStore(settings.data_dir or default_root(), self.redis)
        self._faults = _parse_faults(settings.faults)
        self._was_disabled = False
        self._scene_files: dict[str, str] = {}
        self._products: dict[str, bytes] = {}  # content hash -> scene-pass product
        self._tmpdir: str | None = None
        self._child = RenderChild(settings.memory_limit)
        self.current = ""
        self._stop: threading.Event | None = None
        self._stop_grace = StopGrace(settings.stop_grace)
        self.tiles_rendered = 0
        self.started_at = time.time()

    # ----------------------------------------------------------------- main loop
    def run(self, stop: threading.Event) -> None:
        self._stop = stop
        for kind in ("worker", "blob"):
            for path in remove_orphaned_tempdirs(kind):
                log.warning("removed %s, left by a worker or render process that was killed", path)
        self._tmpdir = private_tempdir("worker")
        heartbeat_stop = threading.Event()
        heartbeat = threading.Thread(target=self._heartbeat_loop, args=(heartbeat_stop,),
                                     name="tessera-heartbeat", daemon=True)
        log.info("worker %s starting (renderer threads: %s, memory limit: %s, tile time "
                 "limit: %g s)", self.name, self.threads,
                 _size(self.settings.memory_limit), self.settings.tile_timeout)
        try:
            self._child.start()  # importing the renderer takes a while: do it up front
            # Alive before taking work: a consumer without a heartbeat is dead.
            self._wait_for_redis(stop, self._beat)
            heartbeat.start()
            self._loop(stop)
        finally:
            heartbeat_stop.set()
            if heartbeat.is_alive():
                heartbeat.join(timeout=5)
            self._child.stop()
            self._leave()
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            log.info("worker %s stopped after %d tiles", self.name, self.tiles_rendered)

    def _loop(self, stop: threading.Event) -> None:
        next_reap = 0.0
        redis_down = False
        while not stop.is_set():
            try:
                if time.monotonic() >= next_reap:
                    self._reap(stop)
                    next_reap = time.monotonic() + REAP_INTERVAL
                if stop.is_set():
                    break
                if self._disabled():
                    stop.wait(IDLE_WAIT)  # (leaves the wake-up tokens to the others)
                    continue
                picked = self.scripts.pick(keys=[rdb.READY],
                                           args=[self.name, repr(time.time()), rdb.job_prefix()])
                if redis_down:
                    log.info("redis is reachable again")
                    redis_down = False
                if not picked:
                    # Queuing work pushes wake-up tokens; without one, look again anyway
                    # after IDLE_WAIT (and reap).
                    self.redis.blpop([rdb.WAKE], timeout=IDLE_WAIT)
                    continue
                job_id, entry_id, raw, started_at = picked
                self._process(_text(job_id), entry_id, {b"task": raw}, _float(started_at))
            except redis.ResponseError as e:
                # E.g. Redis out of memory: the tile stays pending and is retried later.
                log.error("redis refused a command (%s); retrying", e)
                stop.wait(1.0)
            except (redis.ConnectionError, redis.TimeoutError) as e:
                if not redis_down:
                    log.warning("lost redis (%s); retrying", e)
                    redis_down = True
                stop.wait(1.0)

    def _disabled(self) -> bool:
        """An admin disabled this worker (POST /workers/{name}/disable): it takes no new task."""
        disabled = self.redis.hget(rdb.worker_key(self.name), "disabled") is not None
        if disabled != self._was_disabled:
            log.warning("disabled by an admin: taking no new task" if disabled
                        else "enabled again: taking tasks")
            self._was_disabled = disabled
        return disabled

    def _wait_for_redis(self, stop: threading.Event, action) -> None:
        while not stop.is_set():
            try:
                action()
                return
            except (redis.ConnectionError, redis.TimeoutError) as e:
                log.warning("cannot reach redis (%s); retrying", e)
                stop.wait(1.0)
            except redis.ResponseError as e:
                if not _out_of_memory(e):
                    raise
                log.error("redis is out of memory (its maxmemory is reached) and refused this "
                          "worker's registration; retrying")
                stop.wait(1.0)

    # ----------------------------------------------------------------- one tile pass
    def _process(self, job_id: str, entry_id: bytes, fields: dict | None,
                 started_at: float | None = None) -> None:
        """Handles one stream entry; acknowledges it unless Redis itself fails."""
        queue = rdb.job_queue_key(job_id)
        if not fields:  # the entry was deleted from the stream while pending
            self._ack(queue, entry_id)
            return
        try:
            task = TileTask.from_fields(fields)
        except ValueError as e:  # includes pydantic's ValidationError
            log.error("dropping malformed stream entry %s of job %s: %s", entry_id, job_id, e)
            self._ack(queue, entry_id)
            return
        if task.decide:
            self._decide(task, entry_id, started_at)
            return
        if task.scene_pass:
            self._scene_task(task, entry_id)
            return
        tiles_key = rdb.job_tiles_key(job_id)
        if self.redis.hexists(tiles_key, task.field):  # a redelivery after a lost ack
            self._ack(queue, entry_id)
            return
        window = protocol.pass_range(task.settings, task.pass_index)
        if window is None:
            log.error("dropping task for pass %d of tile %d past the job's last pass",
                      task.pass_index, task.tile.index)
            self._ack(queue, entry_id)
            return
        self.current = f"{job_id}/{task.tile.index}/{task.pass_index}"
        try:
            try:
                result, seconds = self._render(task)
            except Abandoned as e:
                if str(e):
                    log.info("job %s tile %d pass %d dropped: %s", job_id, task.tile.index,
                             task.pass_index, e)
                else:
                    log.info("job %s ended while tile %d (pass %d) rendered; dropped it", job_id,
                             task.tile.index, task.pass_index)
                self._ack(queue, entry_id)
                return
            except HandBack:
                self._hand_back(task, entry_id, f"tile {task.tile.index} (pass {task.pass_index})")
                return
            except RenderFailed as e:
                self._failed(task, entry_id, str(e), e.fatal)
                return
            final = self._tile_final(task, result, started_at)
        finally:
            self.current = ""
        if task.settings.lockstep:
            mode, follow = 2, task.decide_task().model_dump_json()
        else:
            mode, follow = (1, "") if final else (0, task.next_pass().model_dump_json())
        args = [job_id, task.field, None, repr(seconds), mode, follow, None, self.name,
                entry_id, task.tile.index, task.pass_index, result.sample_start + result.spp]
        completed = self._store(task, result, args, self._stop)
        if completed is None:
            return  # stopping while Redis refuses writes: the entry stays pending
        self.tiles_rendered += 1
        log.debug("job %s tile %s pass %d rendered in %.3f s", job_id, task.tile.index,
                  task.pass_index, seconds)
        if completed == 1:
            log.info("job %s done", job_id)

    def _render(self, task: TileTask, scene_pass: bool = False):
        """Renders a tile pass in the render process, or with `scene_pass` computes a scene
        pass's product; returns (TileResult or product bytes, seconds)."""
        s, rect = task.settings, task.tile
        self._child.ensure_started()
        product = None if scene_pass else self._scene_product(task)
        scene = self._scene_source(task, self._child.blob_version)
        request = dict(**scene, settings=s.model_dump_json(), tile=rect.model_dump(),
                       pass_index=task.pass_index, threads=self.threads, variance=s.adaptive,
                       default_light=s.default_light,
                       # light and bdpt: the variance layer from batches (convergence.VARIANCE_BATCHES)
                       batches="variance" in s.aovs, fault=self._fault_for(task),
                       scene_pass=scene_pass, scene_product=product)
        job_key = rdb.job_key(task.job_id)

        def abandoned() -> bool:
            self._stop_grace.check(self._stop)  # raises HandBack: the child is killed
            try:
                state = _text(self.redis.hget(job_key, "state"))
            except redis.RedisError:
                return False  # cannot tell: keep rendering
            return state in ("", "failed", "cancelled")

        reply = self._child.render(request, self.settings.tile_timeout, abandoned)
        if reply[0] == "ok":
            if scene.get("blob_out"):
                self._share_blob(task, scene["blob_out"])
            return reply[1], reply[2]
        _, kind, message = reply
        if kind == "scene":
            raise RenderFailed(f"cannot load scene {task.scene_name!r}: {message}", fatal=True)
        if kind == "memory":
            # The child may be left fragmented or in a bad state: start afresh.
            self._child.kill()
            raise RenderFailed(f"exceeded the worker's memory limit of "
                               f"{_size(self.settings.memory_limit)} ({message})", fatal=True)
        raise RenderFailed(message, fatal=False)

    def _scene_task(self, task: TileTask, entry_id: bytes) -> None:
        """A scene-wide task: computes iteration pass_index's product in the render process
        (tessera_base.film.run_scene_pass, as a local render does), stores it content-addressed
        and queues the iteration's tile passes (store_product.lua: once, however often the
        task is delivered; a product depends only on scene, settings, seed and iteration,
        so a reclaimed task computes the same bytes)."""
        job_id, p = task.job_id, task.pass_index
        queue = rdb.job_queue_key(job_id)
        if self.redis.hexists(rdb.job_key(job_id), rdb.product_field(p)):  # a redelivery
            self._ack(queue, entry_id)
            return
        self.current = f"{job_id}/scene/{p}"
        try:
            try:
                product, seconds = self._render(task, scene_pass=True)
            except Abandoned:
                self._ack(queue, entry_id)
                return
            except HandBack:
                self._hand_back(task, entry_id, f"scene pass {p}")
                return
            except RenderFailed as e:
                self._failed(task, entry_id, str(e), e.fatal)
                return
        finally:
            self.current = ""
        self.redis.hincrby(rdb.job_key(job_id), "scene_pass_runs", 1)
        digest = hashlib.sha256(product).hexdigest()
        self._products[digest] = product
        tasks = [t.model_dump_json() for t in task.pass_tasks(p)]
        stored = self.scripts.store_product(keys=self._keys(job_id, task.scene_hash),
                                            args=[job_id, p, digest, product, entry_id,
                                                  repr(time.time()), self.name, repr(seconds), *tasks])
        log.info("job %s: scene pass %d computed in %.3f s (%d bytes)%s", job_id, p, seconds,
                 len(product), "" if stored == 1 else "; it was already stored")

    def _failed(self, task: TileTask, entry_id: bytes, message: str, fatal: bool) -> None:
        where = (f"the scene pass of iteration {task.pass_index} of {task.scene_name!r}" if task.scene_pass
                 else f"tile {task.tile.index} (pass {task.pass_index}) of {task.scene_name!r}")
        if fatal:
            error = message if message.startswith("cannot load scene") else f"{where}: {message}"
            log.error("job %s failed: %s", task.job_id, error)
            self._fail(task.job_id, error, task.scene_hash)
            self._ack(rdb.job_queue_key(task.job_id), entry_id)
            return
        log.warning("job %s: %s failed: %s", task.job_id, where, message)
        keys = self._keys(task.job_id, task.scene_hash) + [rdb.worker_key(self.name), rdb.DEAD_LETTER]
        outcome = _text(self.scripts.fail_tile(keys=keys, args=[
            task.job_id, task.field, task.tile.index, entry_id, self.name, message,
            repr(time.time()), task.max_attempts, protocol.BLOCKLIST_AFTER,
            task.model_dump_json()]))
        if outcome == "poisoned":
            log.error("job %s failed: %s failed %d times", task.job_id, where, task.max_attempts)
        elif outcome == "blocklisted":
            log.warning("this worker is blocklisted for job %s", task.job_id)
            self._fail_if_nobody_left(task.job_id, message)

    def _hand_back(self, task: TileTask, entry_id: bytes, what: str) -> None:
        """Stopping, with the task unfinished after the stop budget: queue it again for
        the other workers (hand_back.lua) rather than leave it pending under this worker."""
        log.warning("stopping: job %s %s is not done after the stop budget of %g s; "
                    "handing it back to the queue", task.job_id, what, self._stop_grace.budget)
        self.scripts.hand_back(keys=self._keys(task.job_id, task.scene_hash),
                               args=[task.job_id, entry_id, self.name, repr(time.time()),
                                     task.model_dump_json(), what])

    def _fail_if_nobody_left(self, job_id: str, last_error: str) -> None:
        """A job every live worker is blocklisted for would wait forever: fail it."""
        blocked = {_text(n) for n in self.redis.smembers(rdb.job_blocklist_key(job_id))}
        for name in self.redis.smembers(rdb.WORKERS):
            name = _text(name)
            if name not in blocked and self.redis.exists(rdb.worker_key(name)):
                return
        self._fail(job_id, f"every live worker is blocklisted for this job; last error: "
                           f"{last_error}")

    def _keys(self, job_id: str, scene_hash: str | None = None) -> list[str]:
        """The KEYS of the job's scripts (redis_schema.job_script_keys)."""
        if scene_hash is None:
            scene_hash = _text(self.redis.hget(rdb.job_key(job_id), "scene_hash"))
        return rdb.job_script_keys(job_id, scene_hash)

    def _fail(self, job_id: str, message: str, scene_hash: str | None = None) -> None:
        self.scripts.fail_job(keys=self._keys(job_id, scene_hash),
                              args=[job_id, repr(time.time()), message])

    def _ack(self, queue: str, entry_id: bytes) -> None:
        # Entries are removed once acknowledged, so the stream holds only open work.
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.xack(queue, rdb.WORKER_GROUP, entry_id)
            pipe.xdel(queue, entry_id)
            pipe.execute()

    def _fault_for(self, task: TileTask) -> str | None:
        target = SCENE_TASK if task.scene_pass else task.tile.index
        for kind, pattern, tile in self._faults:
            if fnmatch.fnmatch(task.scene_name, pattern) and tile in (None, target):
                return kind
        return None



def _parse_faults(spec: str) -> list[tuple[str, str, int | None]]:
    faults = []
    for item in filter(None, (s.strip() for s in spec.split(","))):
        kind, _, rest = item.partition(":")
        pattern, _, tile = rest.partition("#")
        if kind not in ("segv", "abort", "hang", "oom", "exit") or not pattern \
                or not (tile in ("", "scene") or tile.isdigit()):
            raise ValueError(f"bad fault injection rule {item!r}: use KIND:GLOB[#TILE|#scene]")
        faults.append((kind, pattern, SCENE_TASK if tile == "scene" else int(tile) if tile else None))
    return faults


def _size(n: int) -> str:
    return "none" if n <= 0 else f"{n / (1 << 30):g} GiB"


