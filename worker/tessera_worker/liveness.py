"""The worker's liveness: its heartbeat, and the reaper that takes over the tiles held by
workers whose heartbeat expired (and poisons a tile whose workers keep dying)."""
from __future__ import annotations

import logging
import os
import socket
import threading
import time

import redis

from tessera_queue import redis_schema as rdb
from tessera_queue.tasks import TileTask

from .redis_values import text as _text

log = logging.getLogger("tessera.worker")

HEARTBEAT_TTL = 5.0        # seconds a worker counts as alive after its last heartbeat
REAP_INTERVAL = 2.0        # seconds between looks for tiles held by dead workers
CLAIM_MIN_IDLE_MS = 1000   # two reapers do not both claim a tile claimed within this time
MAX_DEATH_DELIVERIES = 10  # a tile whose worker died this often is poisoned


class Liveness:
    """Worker's part that keeps it and the farm's view of the workers alive (a mixin: it
    uses the Worker's redis, name, scripts, _process, _fail and _ack)."""

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
