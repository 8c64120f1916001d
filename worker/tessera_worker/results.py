"""Storing a rendered pass: its splats folded into the job's splat sums in the same
transaction (a pass is summed exactly once however often it is delivered), kept and
retried while Redis refuses writes for lack of memory."""
from __future__ import annotations

import logging
import threading
import time

import redis

from tessera_base import film, protocol
from tessera_queue import redis_schema as rdb
from tessera_queue.tasks import TileTask

from .redis_values import out_of_memory as _out_of_memory

log = logging.getLogger("tessera.worker")

OOM_BACKOFF_MIN = 0.25     # first wait after Redis refused a result for lack of memory
OOM_BACKOFF_MAX = 10.0


class ResultStore:
    """Worker's part that stores results (a mixin: it uses the Worker's redis, name,
    scripts and _keys)."""

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
