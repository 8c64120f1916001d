"""What a job keeps in Redis, and for how long: splat sums instead of a full-frame layer
per tile, the per-job budget, a Redis at its maxmemory, and scenes that live as long as a
job needs them. Real redis-server, uvicorn API and worker processes."""
from __future__ import annotations

import time

import httpx
import numpy as np
import pytest
import redis

from conftest import (CORNELL, farm_image, local_reference, start_api, start_worker, submit,
                      wait_for_job)
from tessera_queue import redis_schema as rdb
from tessera_base.protocol import RenderSettings
from tessera_cli.embedded import redis_server


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape and actual.dtype == expected.dtype == np.float32
    differ = actual.view(np.uint32) != expected.view(np.uint32)
    assert not differ.any(), f"{int(differ.sum())} of {differ.size} channel values differ"


def job_bytes(client: redis.Redis, job_id: str) -> dict[str, int]:
    """MEMORY USAGE of each of the job's keys that hold results (tiles, splat sums)."""
    return {name: client.memory_usage(key, samples=0) or 0
            for name, key in (("tiles", rdb.job_tiles_key(job_id)), ("splats", rdb.job_splats_key(job_id)))}


def wait_until(predicate, timeout: float, what, poll: float = 0.05):
    """Polls `predicate` until true; `what` (a string or a callable making one) says what
    did not happen."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() < deadline, what() if callable(what) else what
        time.sleep(poll)


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("storage")
    api, base = start_api(redis_server, logs)
    workers = [start_worker(redis_server, name, logs) for name in ("s-a", "s-b")]
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes = [api, *workers]
        yield client
    for proc in [*workers, api]:
        proc.stop()


def test_splat_storage_does_not_grow_with_the_tile_count(farm, redis_client, tmp_path):
    """A bdpt job keeps its pixels once and its splats once per pass, whatever the tiling:
    64 tiles keep about what 4 tiles keep (each tile used to store its own full-frame
    splat layer: about 10x more at 64 tiles). The merged image is the local one bit for
    bit either way, so the summing order cannot matter (integer sums)."""
    sizes = {}
    for tile in (64, 16):
        form = dict(width=128, height=128, spp=4, seed=5, max_depth=8, tile_size=tile, integrator="bdpt")
        r = submit(farm, CORNELL, **form)
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        assert wait_for_job(farm, job_id, processes=farm.processes)["state"] == "done"
        sizes[tile] = job_bytes(redis_client, job_id)
        fields = redis_client.hkeys(rdb.job_splats_key(job_id))
        assert fields == [b"0"], "one splat sum for the one pass"
        total = sum(sizes[tile].values())
        assert total <= rdb.job_storage_bound(RenderSettings(**form)), (total, sizes)
        assert_bit_identical(farm_image(farm, job_id, tmp_path), local_reference(form))
        # Every event the scripts wrote is a JobEvent (the one event model).
        for _, fields in redis_client.xrange(rdb.job_events_key(job_id)):
            rdb.JobEvent.from_fields(fields)
    few, many = sum(sizes[64].values()), sum(sizes[16].values())
    # The camera part is the same pixels; 60 more tile headers and sparser sums allow 25 %.
    assert many < 1.25 * few, sizes
    # The splats are a real part of what is stored (so the check above weighs them): had
    # each of the 64 tiles kept even a tenth of a pass's sum, it would fail.
    assert 64 * 0.1 * sizes[16]["splats"] > 0.25 * few, sizes


def test_a_job_over_the_redis_budget_is_refused(redis_server, tmp_path):
    """TESSERA_JOB_REDIS_BUDGET bounds what one job may keep: a job estimated above it is a
    422 that says so before anything is queued; one below it is accepted."""
    small = RenderSettings(width=32, height=32, spp=1, integrator="bdpt")
    large = RenderSettings(width=256, height=256, spp=16, integrator="bdpt")
    budget = rdb.job_storage_bound(small) + 1000
    assert rdb.job_storage_bound(large) > budget
    api, base = start_api(redis_server, tmp_path, job_redis_budget=str(budget))
    try:
        with httpx.Client(base_url=base, timeout=60) as client:
            before = client.get("/jobs").json()["jobs"]
            r = submit(client, CORNELL, width=256, height=256, spp=16, integrator="bdpt")
            assert r.status_code == 422, r.text
            assert "TESSERA_JOB_REDIS_BUDGET" in r.json()["detail"]
            assert "more than the per-job budget" in r.json()["detail"]
            assert client.get("/jobs").json()["jobs"] == before
            r = submit(client, CORNELL, width=32, height=32, spp=1, integrator="bdpt")
            assert r.status_code == 201, r.text
            client.delete(f"/jobs/{r.json()['id']}")
    finally:
        api.stop()


def test_a_full_redis_refuses_writes_and_loses_no_tile(tmp_path):
    """Redis at its maxmemory (noeviction) refuses the worker's result: the worker keeps
    the rendered tile, logs why, retries with a backoff and stores it once there is room;
    a worker started meanwhile waits instead of crashing, and the API answers a new upload
    with a 503 that stores nothing. The image is the local one."""
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        api, base = start_api(rs.url, tmp_path)
        worker = start_worker(rs.url, "oom-a", tmp_path)
        late = None
        try:
            with httpx.Client(base_url=base, timeout=60) as http:
                form = dict(width=64, height=32, spp=192, seed=2, max_depth=8, tile_size=32,
                            integrator="bdpt")
                r = submit(http, CORNELL, **form)
                assert r.status_code == 201, r.text
                job_id = r.json()["id"]
                events = rdb.job_events_key(job_id)
                # The first tile stored (its event), and the worker's heartbeat names the
                # second as the one it renders (seconds of bdpt): make Redis full now, so
                # that the second tile's result meets a full Redis.
                cursor, stored = "0", False
                while not stored:
                    reply = client.xread({events: cursor}, block=30000)
                    assert reply, "no tile was stored\n" + worker.log()
                    for entry_id, fields in reply[0][1]:
                        cursor = entry_id
                        stored = stored or fields.get(b"type") == b"tile"
                second = f"{job_id}/1/0"
                wait_until(lambda: client.hget(rdb.worker_key("oom-a"), "current") == second.encode(), 60,
                           lambda: "the worker never rendered the second tile\n" + worker.log())
                client.config_set("maxmemory", 1)
                wait_until(lambda: "redis is out of memory" in worker.log(200), 60,
                           lambda: "the worker never reported the full Redis\n" + worker.log())
                late = start_late_worker(rs.url, tmp_path)
                wait_until(lambda: "refused this worker's registration" in late.log(200), 60,
                           lambda: "the late worker did not report the full Redis\n" + late.log())
                assert late.alive(), late.log()
                assert client.hlen(rdb.job_tiles_key(job_id)) == 1
                assert client.hget(rdb.job_key(job_id), "state") == b"running"
                # A new job meanwhile: a clear 503, and nothing of it stored.
                refused = submit(http, CORNELL, width=16, height=16, spp=1, seed=77)
                assert refused.status_code == 503 and "full" in refused.json()["detail"], refused.text
                assert refused.headers["retry-after"] == "30"
                assert [j["id"] for j in http.get("/jobs").json()["jobs"]] == [job_id]
                client.config_set("maxmemory", 0)
                status = wait_for_job(http, job_id, processes=[worker, late], expect="done")
                assert_bit_identical(farm_image(http, job_id, tmp_path), local_reference(form))
                assert "keeping it and trying again" in worker.log(400)
                wait_until(lambda: client.exists(rdb.worker_key("oom-late")), 30,
                           lambda: "the late worker never registered\n" + late.log())
        finally:
            for proc in (late, worker, api):
                if proc is not None:
                    proc.stop()
            client.close()


def start_late_worker(url: str, log_dir):
    """A worker process without waiting for its heartbeat (Redis refuses it for now)."""
    import sys

    from conftest import Process, clean_env
    return Process("oom-late", [sys.executable, "-m", "tessera_worker", "--name", "oom-late",
                                "--threads", "1", "--heartbeat-ttl", "2", "--log-level", "DEBUG"],
                   log_dir, clean_env(REDIS_URL=url))


def test_a_scene_lives_as_long_as_a_job_needs_it(tmp_path):
    """With a scene retention of 2 s, a queued job and a paused one outlast it (before:
    their scene expired under them and the jobs failed on the missing scene). The scene
    expires only after the last job that needs it has ended. Synchronised on the expiry of
    the pre-flight result, which gets the same retention at the same moment."""
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        api, base = start_api(rs.url, tmp_path, scene_retention="2")
        worker = None
        try:
            with httpx.Client(base_url=base, timeout=60) as http:
                form = dict(width=32, height=32, spp=2, seed=1, max_depth=8, tile_size=16)
                queued = submit(http, CORNELL, **form).json()["id"]
                paused = submit(http, CORNELL, **form).json()["id"]
                assert http.post(f"/jobs/{paused}/pause").json()["state"] == "paused"
                scene_hash = client.hget(rdb.job_key(queued), "scene_hash").decode()
                scene = rdb.scene_key(scene_hash)
                wait_until(lambda: not client.exists(rdb.preflight_key(scene_hash, ".usda")), 30,
                           "the pre-flight result never expired")
                assert client.exists(scene), "the scene expired while two jobs need it"
                assert client.pttl(scene) == -1
                assert client.smembers(rdb.scene_jobs_key(scene_hash)) == {queued.encode(), paused.encode()}
                worker = start_worker(rs.url, "scene-w", tmp_path)
                assert wait_for_job(http, queued, processes=[worker])["state"] == "done"
                # One job still needs it: still no expiry.
                assert client.pttl(scene) == -1
                assert http.post(f"/jobs/{paused}/resume").status_code == 200
                status = wait_for_job(http, paused, processes=[worker], expect="done")
                # The last job ended: the retention starts, and the scene goes.
                assert 0 < client.pttl(scene) <= 2000
                expected = local_reference(form)
                for job_id in (queued, paused):
                    assert_bit_identical(farm_image(http, job_id, tmp_path), expected)
                wait_until(lambda: not client.exists(scene), 30, "the released scene never expired")
        finally:
            for proc in (worker, api):
                if proc is not None:
                    proc.stop()
            client.close()
