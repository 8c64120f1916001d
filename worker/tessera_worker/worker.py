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

import contextlib
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
from pathlib import PurePosixPath

import redis

from tessera_base import film, integrators, protocol
from tessera_base import convergence
from tessera_queue import redis_schema as rdb
from tessera_queue.data_store import DataStore, ObjectMissing, default_root, is_digest
from tessera_base.process import private_tempdir, remove_orphaned_tempdirs
from tessera_queue.tasks import TileTask

from .child import Abandoned, RenderChild, RenderFailed
from .settings import WorkerSettings
from .stop_grace import HandBack, StopGrace

log = logging.getLogger("tessera.worker")

HEARTBEAT_TTL = 5.0        # seconds a worker counts as alive after its last heartbeat
IDLE_WAIT = 1.0            # longest wait for a wake-up token when there is no work
REAP_INTERVAL = 2.0        # seconds between looks for tiles held by dead workers
CLAIM_MIN_IDLE_MS = 1000   # two reapers do not both claim a tile claimed within this time
MAX_DEATH_DELIVERIES = 10  # a tile whose worker died this often is poisoned
OOM_BACKOFF_MIN = 0.25     # first wait after Redis refused a result for lack of memory
OOM_BACKOFF_MAX = 10.0
SCENE_FILES = 8            # scene files kept on local disk (least recently used go)
PRODUCTS_KEPT = 4          # scene-pass products kept in memory (least recently used go)
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


class Worker:
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

    def _store(self, task: TileTask, result, args: list, stop: threading.Event | None):
        """Stores a rendered pass (store_tile.lua): the result with its splats folded into the
        job's splat sums, in one transaction, so that a pass is summed exactly once however
        often it is delivered. Redis refusing the write for lack of memory (maxmemory with
        noeviction) does not lose the pass: it is kept here and stored again after a
        backoff, until it fits or the worker stops (then the entry stays pending and is
        rendered again). Returns the script's result, or None if it gave up."""
        keys = self._keys(task.job_id, task.scene_hash) + [rdb.worker_key(self.name)]
        names = film.SplatSums.fields_of(result)
        s = task.settings
        delay = OOM_BACKOFF_MIN
        while True:
            try:
                if not names:
                    data = protocol.encode_tile(task.tile, **_tile_fields(result))
                    return self.scripts.store_tile(keys=keys, args=_store_args(args, data))
                return self._store_folded(task, result, args, keys, names)
            except redis.ResponseError as e:
                if not _out_of_memory(e):
                    raise
                if stop is None or stop.is_set():
                    log.error("redis is out of memory; leaving tile %d (pass %d) of job %s "
                              "pending for a retry", task.tile.index, task.pass_index, task.job_id)
                    return None
                log.error("redis is out of memory (its maxmemory is reached) and refused tile %d "
                          "(pass %d) of job %s, %dx%d; keeping it and trying again in %.1f s",
                          task.tile.index, task.pass_index, task.job_id, s.width, s.height, delay)
                if stop.wait(delay):
                    return None
                delay = min(2 * delay, OOM_BACKOFF_MAX)

    def _store_folded(self, task: TileTask, result, args: list, keys: list, names: list[str]):
        s = task.settings
        splats_key = rdb.job_splats_key(task.job_id)
        with self.redis.pipeline(transaction=True) as pipe:
            while True:
                try:
                    pipe.watch(splats_key)
                    stored = pipe.hmget(splats_key, names)
                    sums = film.SplatSums(s.width, s.height)
                    for name, data in zip(names, stored):
                        if data is not None:
                            sums.decode_into(name, data)
                    light = sums.fold(result)
                    pairs = [v for n in names for v in (n, sums.encode(n))]
                    data = protocol.encode_tile(task.tile, **_tile_fields(light))
                    pipe.multi()
                    self.scripts.store_tile(keys=keys, args=_store_args(args, data, pairs),
                                            client=pipe)
                    return pipe.execute()[0]
                except redis.WatchError:
                    continue  # another tile of the job was stored meanwhile: add again

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

    def _scene_product(self, task: TileTask) -> bytes | None:
        """The product a tile pass of a scene-pass integrator reads (None for the others):
        fetched once per worker and iteration, kept by its content hash."""
        if not integrators.scene_passes(task.settings.integrator):
            return None
        digest = _text(self.redis.hget(rdb.job_key(task.job_id), rdb.product_field(task.pass_index)))
        product = self._products.get(digest) if digest else None
        if product is None and digest:
            product = self.redis.hget(rdb.job_products_key(task.job_id), digest)
        if product is None:
            decided = _text(self.redis.hget(rdb.job_key(task.job_id), "decided_pass"))
            if decided is not None and int(decided) >= task.pass_index:
                # A late duplicate of a tile its pass already holds (decide_pass.lua dropped
                # the pass's product with the barrier): nothing to render.
                raise Abandoned(f"pass {task.pass_index} is complete")
            raise RenderFailed(f"the scene pass {task.pass_index} product is missing", fatal=True)
        self._products[digest] = self._products.pop(digest, product)  # most recently used last
        while len(self._products) > PRODUCTS_KEPT:
            self._products.pop(next(iter(self._products)))
        return product

    def _tile_final(self, task: TileTask, this, started_at: float | None) -> bool:
        """Whether the tile needs no further pass (per-tile noise target)."""
        s, rect = task.settings, task.tile
        if not s.adaptive or s.lockstep:
            return True  # lockstep: the pass barrier decides (_decide)
        earlier = []
        if task.pass_index > 0:
            fields = [rdb.result_field(rect.index, p) for p in range(task.pass_index)]
            stored = self.redis.hmget(rdb.job_tiles_key(task.job_id), fields)
            if any(d is None for d in stored):
                # Cannot happen (a pass is queued only after the previous one is stored)
                # unless the job's results expired; finish the tile with what it has.
                return True
            earlier = [protocol.decode_tile(d) for d in stored]
        mean, var, samples = convergence.combine_passes(earlier + [this])
        final = convergence.tile_finished(s, task.pass_index, mean, var, samples)
        if not final and s.time_limit is not None:
            if started_at is None:
                started_at = _float(self.redis.hget(rdb.job_key(task.job_id), "started_at"))
            final = started_at is not None and time.time() - started_at >= s.time_limit
        return final

    def _decide(self, task: TileTask, entry_id: bytes, started_at: float | None) -> None:
        """A lockstep pass barrier: adds the pass's whole-image estimate to the job's
        accumulator and queues the next pass for every tile, or finishes the job. Tiles are
        read one at a time, so memory stays at a few full frames."""
        job_id, s, p = task.job_id, task.settings, task.pass_index
        key = rdb.job_key(job_id)
        # Read together (decide_pass.lua writes both at once): read apart, a barrier
        # reclaimed from a slow worker could see the other's accumulator of pass p + 1 with
        # the decision still unread, and fail a healthy job.
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hget(key, "decided_pass")
            pipe.get(rdb.job_passes_key(job_id))
            decided, accumulated = pipe.execute()
        decided = _text(decided)
        if decided and int(decided) >= p:  # a redelivery
            self._ack(rdb.job_queue_key(job_id), entry_id)
            return
        acc = convergence.PassAccumulator.from_bytes(accumulated)
        if acc.passes != p:
            self._fail(job_id, f"pass barrier {p} found {acc.passes} passes accumulated",
                       task.scene_hash)
            self._ack(rdb.job_queue_key(job_id), entry_id)
            return
        grid = protocol.job_tiles(s)
        tiles_key = rdb.job_tiles_key(job_id)
        results = []
        for rect in grid:
            data = self.redis.hget(tiles_key, rdb.result_field(rect.index, p))
            if data is None:  # expired or the job was deleted under us
                log.warning("job %s: pass %d of tile %d is gone; barrier dropped", job_id, p,
                            rect.index)
                self._ack(rdb.job_queue_key(job_id), entry_id)
                return
            try:
                results.append(protocol.decode_tile(data))
            except ValueError as e:  # corrupt: the job cannot be merged either
                self._fail(job_id, f"tile {rect.index} pass {p}: unreadable result: {e}",
                           task.scene_hash)
                self._ack(rdb.job_queue_key(job_id), entry_id)
                return
        sums = film.SplatSums(s.width, s.height)
        name = film.SplatSums.pass_field(p)
        stored = self.redis.hget(rdb.job_splats_key(job_id), name)
        if stored is not None:
            try:
                sums.decode_into(name, stored)
            except ValueError as e:
                self._fail(job_id, f"pass {p}: unreadable splat sum: {e}", task.scene_hash)
                self._ack(rdb.job_queue_key(job_id), entry_id)
                return
        acc = acc.add(protocol.in_crop(s, film.pass_image(s.width, s.height, results, sums)), results[0].spp)
        del results
        finished = convergence.image_finished(s, p, acc)
        if not finished and s.adaptive and s.time_limit is not None:  # a fixed spp renders every pass
            if started_at is None:
                started_at = _float(self.redis.hget(key, "started_at"))
            finished = started_at is not None and time.time() - started_at >= s.time_limit
        error = acc.error()
        log.info("job %s: pass %d done, image noise %s; %s", job_id, p,
                 "unknown" if error is None else f"{error:.3%}", "finished" if finished else "next pass")
        tasks = [] if finished else [t.model_dump_json() for t in task.iteration_tasks(p + 1)]
        if self.scripts.decide_pass(keys=self._keys(job_id, task.scene_hash),
                                    args=[job_id, p, 1 if finished else 0, repr(time.time()),
                                          entry_id, acc.to_bytes(), *tasks]) == 1:
            log.info("job %s done", job_id)

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

    def _scene_source(self, task: TileTask, blob_version: str | None) -> dict:
        """Where the render process gets the task's scene: the translated blob another
        worker stored in the data store (no USD parsing), else the scene file, translated
        here and written as a blob (`blob_out`) that _share_blob then stores for the others."""
        suffix = PurePosixPath(task.scene_name).suffix.lower()
        level, camera = task.settings.subdivision_level, task.settings.camera
        # A subdivision level other than the default translates to other triangles, another
        # camera to other camera-relative coordinates: each its own blob (and cached Scene),
        # never the default one.
        variant = "" if level is None else f".subdiv{level}"
        # The same bytes as a .usdz and as a .zip may have different root layers (the
        # package's first member; the zip's named or only top-level one): never share.
        if suffix == ".usdz":
            variant = ".usdz" + variant
        if camera is not None:
            variant += ".cam" + hashlib.sha256(camera.encode()).hexdigest()[:16]
        # Another time code or shutter: other positions and motion steps.
        frame, shutter = task.settings.frame, task.settings.shutter
        if frame is not None or shutter is not None:
            variant += ".t" + hashlib.sha256(repr((frame, shutter)).encode()).hexdigest()[:16]
        # Other variant selections: another composed stage.
        selections = [list(protocol.parse_variant(v)) for v in task.settings.variants or ()]
        if selections:
            variant += ".v" + hashlib.sha256(repr(selections).encode()).hexdigest()[:16]
        source = {"scene_key": f"{task.scene_hash}{variant}{suffix}", "scene_path": None,
                  "blob_path": None, "blob_out": None, "subdivision_level": level, "camera": camera,
                  "frame": frame, "shutter": None if shutter is None else list(shutter),
                  "variants": selections}
        if blob_version is None:
            source["scene_path"] = self._scene_file(task)
            return source
        blob_version += variant
        name = f"{task.scene_hash}.{blob_version}.blob"
        path = self._scene_files.get(name)
        if path is not None and os.path.exists(path):
            self._scene_files[name] = self._scene_files.pop(name)
            source["blob_path"] = path
            return source
        named = self.redis.hget(rdb.scene_key(task.scene_hash), rdb.translated_field(blob_version))
        if named is not None and not is_digest(named):
            # The blob itself, as farms before the data store kept it (until the scene expires).
            path = os.path.join(self._tmpdir, name)
            with open(path, "wb") as f:
                f.write(named)
            self._remember_file(name, path)
            source["blob_path"] = path
            return source
        digest = _text(named)
        if digest:
            path = os.path.join(self._tmpdir, name)
            try:
                self.data.copy_to(digest, path)
                self._remember_file(name, path)
                source["blob_path"] = path
                return source
            except ObjectMissing as exc:
                log.warning("translating %s here: its translated scene is not usable: %s",
                            task.scene_name, exc)
        source["scene_path"] = self._scene_file(task)
        source["blob_out"] = os.path.join(self._tmpdir, name)
        return source

    def _share_blob(self, task: TileTask, path: str) -> None:
        """Stores a blob this worker translated in the data store, named once (HSETNX
        semantics) in the scene's hash, which then holds it."""
        if not os.path.exists(path):
            return
        self.redis.hincrby(rdb.STATS, "scene_translations", 1)
        name = os.path.basename(path)
        self._remember_file(name, path)
        blob_version = name[len(task.scene_hash) + 1:-len(".blob")]
        hasher = hashlib.sha256()
        with open(path, "rb") as f:
            while chunk := f.read(1 << 20):
                hasher.update(chunk)
        digest, size = hasher.hexdigest(), os.path.getsize(path)
        # Held by the scene's own hash, so that it lives exactly as long as the scene; only
        # if the scene is still there (a blob of an expired scene would be swept at once).
        key, field = rdb.scene_key(task.scene_hash), rdb.translated_field(blob_version)
        with self.redis.pipeline(transaction=True) as pipe:
            try:
                pipe.watch(key)
                if not pipe.exists(key):
                    return
                named = _text(pipe.hget(key, field))
                if named:
                    pipe.unwatch()
                    if named == digest:  # the same bytes: restores a file that went missing
                        self.data.write_file(digest, path)
                    return
                pipe.multi()
                pipe.hset(key, field, digest)
                self.data.hold(pipe, digest, size, key)  # index first: see data_store
                pipe.execute()
            except redis.WatchError:
                return  # the scene changed meanwhile (another blob, an expiry): skip sharing
        self.data.write_file(digest, path)

    def _remember_file(self, name: str, path: str) -> None:
        self._scene_files[name] = path
        while len(self._scene_files) > SCENE_FILES:
            old = next(iter(self._scene_files))
            path = self._scene_files.pop(old)
            with contextlib.suppress(OSError):
                os.unlink(path)
                if os.path.dirname(path) != self._tmpdir:  # a scene's own directory
                    os.rmdir(os.path.dirname(path))

    def _scene_file(self, task: TileTask) -> str:
        """A local file with the task's scene, alone in a directory of its own under the
        name the API's pre-flight gave it (protocol.scene_file_name): the bundle a loose
        layer sees here is the one that passed pre-flight, and holds no other scene."""
        suffix = PurePosixPath(task.scene_name).suffix.lower()
        key = f"{task.scene_hash}{suffix}"
        path = self._scene_files.get(key)
        if path is not None and os.path.exists(path):
            self._scene_files[key] = self._scene_files.pop(key)  # most recently used last
            return path
        if not self.redis.exists(rdb.scene_key(task.scene_hash)):
            raise RenderFailed(f"cannot load scene {task.scene_name!r}: scene "
                               f"{task.scene_hash} is missing from the store", fatal=True)
        os.makedirs(os.path.join(self._tmpdir, task.scene_hash), exist_ok=True)
        path = os.path.join(self._tmpdir, task.scene_hash, protocol.scene_file_name(suffix))
        try:
            try:
                self.data.copy_to(task.scene_hash, path)
            except ObjectMissing:
                if not self._adopt_legacy_scene(task.scene_hash):
                    raise
                self.data.copy_to(task.scene_hash, path)
        except ObjectMissing as exc:
            # This worker's data directory, not the scene: another worker may render it.
            raise RenderFailed(f"cannot read scene {task.scene_name!r}: {exc}", fatal=False) from None
        self._remember_file(key, path)
        return path

    def _adopt_legacy_scene(self, scene_hash: str) -> bool:
        """Moves a scene's bytes that a farm before the data store kept in its hash (field
        `data`) into the data store; False if there are none."""
        key = rdb.scene_key(scene_hash)
        data = self.redis.hget(key, "data")
        if data is None or hashlib.sha256(data).hexdigest() != scene_hash:
            return False
        with self.redis.pipeline(transaction=True) as pipe:
            self.data.hold(pipe, scene_hash, len(data), key)  # index first: see data_store
            pipe.hset(key, "size", len(data))
            pipe.execute()
        self.data.write_bytes(scene_hash, data)
        self.redis.hdel(key, "data")
        return True

    def _fault_for(self, task: TileTask) -> str | None:
        target = SCENE_TASK if task.scene_pass else task.tile.index
        for kind, pattern, tile in self._faults:
            if fnmatch.fnmatch(task.scene_name, pattern) and tile in (None, target):
                return kind
        return None

    # ----------------------------------------------------------------- liveness
    def _beat(self) -> None:
        key = rdb.worker_key(self.name)
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.hset(key, mapping={"host": socket.gethostname(), "pid": os.getpid(),
                                    "started_at": repr(self.started_at),
                                    "beat_at": repr(time.time()), "current": self.current})
            pipe.hsetnx(key, "tiles_done", 0)
            pipe.hsetnx(key, "failures", 0)
            pipe.pexpire(key, int(self.heartbeat_ttl * 1000))
            pipe.sadd(rdb.WORKERS, self.name)
            pipe.execute()

    def _heartbeat_loop(self, stop: threading.Event) -> None:
        interval = max(0.1, self.heartbeat_ttl / 5)
        while not stop.wait(interval):
            try:
                self._beat()
            except redis.RedisError as e:
                log.debug("heartbeat failed: %s", e)

    def _alive(self, name: str) -> bool:
        return bool(self.redis.exists(rdb.worker_key(name)))

    def _reap(self, stop: threading.Event) -> None:
        """Claims and renders the tiles held by workers whose heartbeat has expired, then
        removes those workers from the queues' groups."""
        # Counted so that /workers and the tests can tell that a reaper looked.
        self.redis.hincrby(rdb.worker_key(self.name), "reaps", 1)
        for job_id in [_text(j) for j in self.redis.smembers(rdb.ACTIVE)]:
            queue = rdb.job_queue_key(job_id)
            try:
                summary = self.redis.xpending(queue, rdb.WORKER_GROUP)
            except redis.ResponseError:  # the queue ended (job finished) meanwhile
                continue
            for consumer in summary.get("consumers") or []:
                dead = _text(consumer["name"])
                mine = dead == self.name
                if not mine and self._alive(dead):
                    continue
                if mine:
                    # The reaper runs between tiles, so an entry of ours is not being
                    # rendered: Redis failed while it was being stored. Render it again.
                    log.info("retrying %s tile(s) of job %s left pending by a redis error",
                             consumer["pending"], job_id)
                else:
                    log.info("worker %s is gone; taking over its %s pending tile(s) of job %s",
                             dead, consumer["pending"], job_id)
                for pending in self.redis.xpending_range(queue, rdb.WORKER_GROUP, min="-",
                                                         max="+", count=100, consumername=dead):
                    if stop.is_set():
                        return
                    # One at a time, so that a tile is not held while others render.
                    claimed = self.redis.xclaim(queue, rdb.WORKER_GROUP, self.name,
                                                CLAIM_MIN_IDLE_MS, [pending["message_id"]])
                    for entry_id, fields in claimed:
                        if not mine:
                            self.redis.hincrby(rdb.STATS, "reclaimed", 1)
                        if pending["times_delivered"] >= MAX_DEATH_DELIVERIES:
                            self._poison_by_deaths(job_id, entry_id, fields,
                                                   pending["times_delivered"])
                        else:
                            self._process(job_id, entry_id, fields)
                if not mine and self.scripts.drop_idle_consumer(keys=[queue],
                                                         args=[rdb.WORKER_GROUP, dead]):
                    log.info("removed dead worker %s from job %s's queue", dead, job_id)
        for name in [_text(n) for n in self.redis.smembers(rdb.WORKERS)]:
            if name != self.name and not self._alive(name):
                self.redis.srem(rdb.WORKERS, name)

    def _poison_by_deaths(self, job_id: str, entry_id: bytes, fields, deliveries: int) -> None:
        try:
            tile = TileTask.from_fields(fields or {}).tile.index
        except ValueError:
            tile = "?"
        message = (f"tile {tile} was delivered {deliveries} times and the worker holding it "
                   f"died each time")
        self._fail(job_id, message)
        self._ack(rdb.job_queue_key(job_id), entry_id)

    def _leave(self) -> None:
        """On a clean exit: stop counting as alive."""
        try:
            self.redis.delete(rdb.worker_key(self.name))
            self.redis.srem(rdb.WORKERS, self.name)
            for job_id in [_text(j) for j in self.redis.smembers(rdb.ACTIVE)]:
                self.scripts.drop_idle_consumer(keys=[rdb.job_queue_key(job_id)],
                                         args=[rdb.WORKER_GROUP, self.name])
        except redis.RedisError as e:
            log.debug("could not leave cleanly: %s", e)


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


def _text(value) -> str:
    if value is None:
        return ""
    return value.decode() if isinstance(value, bytes) else str(value)


def _float(value) -> float | None:
    text = _text(value)
    return float(text) if text else None


def _out_of_memory(error: redis.ResponseError) -> bool:
    """Redis refused a write at its maxmemory (noeviction); redis-py strips the OOM code
    from some of these (errors inside scripts and transactions)."""
    return isinstance(error, redis.exceptions.OutOfMemoryError) or "maxmemory" in str(error)


def _tile_fields(result) -> dict:
    """encode_tile's keyword arguments for a TileResult."""
    return dict(rgba=result.rgba, pass_index=result.pass_index, sample_start=result.sample_start,
                spp=result.spp, variance=result.variance, splat_rect=result.splat_rect,
                splat=result.splat, light_paths=result.light_paths, aovs=result.aovs,
                splat_exponent=result.splat_exponent, batches=result.batches)


def _store_args(args: list, data: bytes, pairs: list = ()) -> list:
    """store_tile.lua's ARGV: `args` with the encoded result and the time filled in, then
    the splat sum (field, value) pairs."""
    out = list(args)
    out[2], out[6] = data, repr(time.time())
    return out + [len(pairs) // 2, *pairs]
