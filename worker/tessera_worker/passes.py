"""When a job's tiles get another pass: per-tile stopping, and the pass barrier of a
lockstep job. The stopping rules themselves (noise target, max_spp, time limit) are
tessera_base.convergence's, which local renders use too."""
from __future__ import annotations

import logging
import time

from tessera_base import convergence, film, protocol
from tessera_queue import redis_schema as rdb
from tessera_queue.tasks import TileTask

from .redis_values import text as _text, to_float as _float

log = logging.getLogger("tessera.worker")


class PassPolicy:
    """Worker's part that decides on further passes (a mixin: it uses the Worker's redis,
    scripts, _fail, _ack and _keys)."""

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
        return convergence.tile_stops(s, task.pass_index, mean, var, samples,
                                      self._elapsed(task.job_id, started_at))

    def _elapsed(self, job_id: str, started_at: float | None):
        """Seconds since the job started, for convergence's time limit: read from Redis
        only when asked (only a render not stopped by its noise asks)."""
        def elapsed() -> float | None:
            start = started_at if started_at is not None else _float(
                self.redis.hget(rdb.job_key(job_id), "started_at"))
            return None if start is None else time.time() - start
        return elapsed

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
        finished = convergence.image_stops(s, p, acc, self._elapsed(job_id, started_at))
        error = acc.error()
        log.info("job %s: pass %d done, image noise %s; %s", job_id, p,
                 "unknown" if error is None else f"{error:.3%}", "finished" if finished else "next pass")
        tasks = [] if finished else [t.model_dump_json() for t in task.iteration_tasks(p + 1)]
        if self.scripts.decide_pass(keys=self._keys(job_id, task.scene_hash),
                                    args=[job_id, p, 1 if finished else 0, repr(time.time()),
                                          entry_id, acc.to_bytes(), *tasks]) == 1:
            log.info("job %s done", job_id)
