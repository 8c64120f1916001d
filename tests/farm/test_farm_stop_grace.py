"""A worker stopped mid-tile (SIGTERM, as Kubernetes and Docker stop a container) within
its stop budget (TESSERA_WORKER_STOP_GRACE): real redis-server, API and worker processes,
one long tile.

- Budget too short for the tile: the worker hands the tile back to the queue and exits 0;
  a second worker takes it from the queue (no reaper claim) and the image is the local
  render.
- Budget long enough: the worker finishes and stores the tile, then exits 0.

The tests synchronise on the worker holding the tile (its pending stream entry) and on
the process's exit, never on elapsed time."""
from __future__ import annotations

import signal
import sys
import time

import httpx
import numpy as np
import pytest
import redis

from conftest import (CORNELL, STARTUP_TIMEOUT, Process, clean_env, farm_image, local_reference,
                      start_api, submit, wait_for_job)
from tessera_queue import redis_schema as rdb

pytestmark = pytest.mark.slow

# One tile of about 2 M samples: seconds on one thread, far longer than the budget of the
# first test plus the half second the worker takes to notice a stop.
FORM = dict(width=32, height=32, tile_size=32, spp=2048, seed=11, max_depth=8)
# A heartbeat that outlives the tile: while the worker renders, no reaper may take it.
LONG_HEARTBEAT = 60.0
EXIT_TIMEOUT = 60.0


def start_worker(redis_url: str, name: str, log_dir, stop_grace: float,
                 heartbeat_ttl: float = 2.0) -> Process:
    """conftest.start_worker with a stop budget (--stop-grace)."""
    proc = Process(name, [sys.executable, "-m", "tessera_worker", "--name", name,
                          "--threads", "1", "--heartbeat-ttl", str(heartbeat_ttl),
                          "--tile-timeout", "600", "--stop-grace", str(stop_grace),
                          "--log-level", "DEBUG"], log_dir, clean_env(REDIS_URL=redis_url))
    client = redis.Redis.from_url(redis_url)
    deadline = time.monotonic() + STARTUP_TIMEOUT
    try:
        while not client.exists(rdb.worker_key(name)):
            assert proc.alive(), f"worker {name} exited at startup\n" + proc.log()
            assert time.monotonic() < deadline, f"worker {name} did not start\n" + proc.log()
            time.sleep(0.05)
    finally:
        client.close()
    return proc


def wait_rendering(client: redis.Redis, worker: Process, name: str, job_id: str) -> None:
    """Until the worker holds the job's tile (its pending entry: taken, not yet stored)."""
    deadline = time.monotonic() + 120
    while not client.xpending_range(rdb.job_queue_key(job_id), rdb.WORKER_GROUP, min="-",
                                    max="+", count=1, consumername=name):
        assert worker.alive(), worker.log()
        assert time.monotonic() < deadline, f"{name} never took the tile\n" + worker.log()
        time.sleep(0.01)


def stats(client: redis.Redis, key: str) -> int:
    return int(client.hget(rdb.STATS, key) or 0)


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("stop-grace")
    api, base = start_api(redis_server, logs)
    with httpx.Client(base_url=base, timeout=60) as client:
        client.redis_url, client.log_dir, client.processes = redis_server, logs, [api]
        yield client
    api.stop()


@pytest.fixture(scope="module")
def reference():
    return local_reference(FORM)


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    differ = actual.view(np.uint32) != expected.view(np.uint32)
    assert not differ.any(), f"{int(differ.sum())} of {differ.size} values differ"


def test_a_tile_not_done_within_the_budget_is_handed_back(farm, redis_client, reference, tmp_path):
    stopping = start_worker(farm.redis_url, "sg-stopping", tmp_path, stop_grace=0.5,
                            heartbeat_ttl=LONG_HEARTBEAT)
    taker = None
    try:
        handed, reclaimed = stats(redis_client, "handed_back"), stats(redis_client, "reclaimed")
        r = submit(farm, CORNELL, **FORM)
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        wait_rendering(redis_client, stopping, "sg-stopping", job_id)
        stopping.popen.send_signal(signal.SIGTERM)
        assert stopping.popen.wait(timeout=EXIT_TIMEOUT) == 0, stopping.log()
        # Started only now, so that the stop cannot come after the tile is done however
        # slowly a worker starts. A tile left pending by the stopped worker would reach
        # this one through its reaper (counted as reclaimed), a handed-back one through
        # the queue.
        taker = start_worker(farm.redis_url, "sg-taker", tmp_path, stop_grace=600)
        log = stopping.log(200)
        assert f"job {job_id} tile 0 (pass 0) is not done after the stop budget of 0.5 s" in log, log
        assert "rendered in" not in log, log  # it stopped rendering rather than finished
        assert not redis_client.exists(rdb.worker_key("sg-stopping"))
        status = wait_for_job(farm, job_id, timeout=120, processes=[taker, *farm.processes], expect="done")
        assert stats(redis_client, "handed_back") == handed + 1
        assert stats(redis_client, "reclaimed") == reclaimed  # no reaper was involved
        assert int(redis_client.hget(rdb.worker_key("sg-taker"), "tiles_done")) == 1
        lines = [line.decode() for line in redis_client.lrange(rdb.job_log_key(job_id), 0, -1)]
        assert any("tile 0 (pass 0) handed back by stopping worker sg-stopping" in line
                   for line in lines), lines
        assert not any("failed" in line for line in lines), lines  # not counted as a failure
        assert_bit_identical(farm_image(farm, job_id, tmp_path), reference)
    finally:
        stopping.stop()
        if taker is not None:
            taker.stop()


def test_a_tile_done_within_the_budget_is_finished_before_the_exit(farm, redis_client, reference,
                                                                   tmp_path):
    worker = start_worker(farm.redis_url, "sg-finisher", tmp_path, stop_grace=600,
                          heartbeat_ttl=LONG_HEARTBEAT)
    try:
        handed = stats(redis_client, "handed_back")
        r = submit(farm, CORNELL, **FORM)
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        wait_rendering(redis_client, worker, "sg-finisher", job_id)
        worker.popen.send_signal(signal.SIGTERM)
        assert worker.popen.wait(timeout=EXIT_TIMEOUT + 120) == 0, worker.log()
        assert f"job {job_id} tile 0 pass 0 rendered" in worker.log(200), worker.log()
        # The only worker is gone: the job is done because it stored the tile before leaving.
        status = wait_for_job(farm, job_id, timeout=10, processes=farm.processes, expect="done")
        assert stats(redis_client, "handed_back") == handed
        assert_bit_identical(farm_image(farm, job_id, tmp_path), reference)
    finally:
        worker.stop()
