"""The farm under faults and load, with real processes: workers SIGKILLed mid-tile while
ten jobs run; Redis (append-only), the API and all workers restarted mid-job; fifty jobs
submitted at once; the `tessera submit` client. Every image must equal its local render
bit for bit."""
from __future__ import annotations

import os
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack

import httpx
import numpy as np
import pytest
import redis

from conftest import (CORNELL, child_pids, clean_env, farm_image, is_running, local_reference, start_api,
                      start_worker, submit, wait_for_job)
from tessera_base import images, protocol
from tessera_queue import redis_schema as rdb
from tessera_cli.embedded import free_port, redis_server as local_redis, stop_processes
from tessera_service.redis_acl import Credentials




def assert_bit_identical(actual: np.ndarray, expected: np.ndarray, what: str = "") -> None:
    assert actual.shape == expected.shape, what
    differ = actual.view(np.uint32) != expected.view(np.uint32)
    assert not differ.any(), f"{what}: {int(differ.sum())} of {differ.size} values differ"


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("resilience")
    api_proc, base = start_api(redis_server, logs)
    workers = [start_worker(redis_server, f"c-{i}", logs) for i in range(3)]
    with httpx.Client(base_url=base, timeout=60) as client:
        client.api = api_proc
        client.workers = workers
        client.redis_url, client.log_dir = redis_server, logs
        yield client
    for proc in [*client.workers, api_proc]:
        proc.stop()


def test_chaos_worker_kills_while_ten_jobs_run(farm, redis_client, tmp_path):
    """Six workers are SIGKILLed in turn, each while its render process holds a tile of one of
    ten queued jobs; then three fresh workers take over the dead workers' tiles. All ten jobs
    complete, every image equals its local render, and no render process outlives its worker.
    The victims hang on their tile (fault injection), so each kill is known to hit a tile in
    flight, however fast or slow the machine."""
    for w in farm.workers:
        w.stop()
    scene = tmp_path / "chaos.usda"
    shutil.copy(CORNELL, scene)
    forms = [dict(width=48, height=48, spp=384, seed=seed, max_depth=16, tile_size=16)
             for seed in range(10)]
    ids = []
    for form in forms:
        r = submit(farm, scene, **form)
        assert r.status_code == 201, r.text
        ids.append(r.json()["id"])
    queues = [rdb.job_queue_key(job_id) for job_id in ids]
    reclaimed_before = int(redis_client.hget(rdb.STATS, "reclaimed") or 0)
    orphans: list[int] = []  # render processes of killed workers
    for kill in range(6):
        name = f"victim-{kill}"
        victim = start_worker(farm.redis_url, name, farm.log_dir, faults="hang:chaos*.usda")
        deadline = time.monotonic() + 60
        while not any(redis_client.xpending_range(q, rdb.WORKER_GROUP, "-", "+", 1,
                                                  consumername=name) for q in queues):
            assert time.monotonic() < deadline, f"{name} never took a tile\n" + victim.log()
            time.sleep(0.01)
        while not (children := child_pids(victim.pid)):  # the render process of its tile
            assert time.monotonic() < deadline, f"{name} has no render process\n" + victim.log()
            time.sleep(0.01)
        os.kill(victim.pid, signal.SIGKILL)
        victim.popen.wait(timeout=10)
        victim.stop()
        orphans.extend(children)
    states = [farm.get(f"/jobs/{job_id}").json()["state"] for job_id in ids]
    assert not any(s in protocol.FINAL_STATES for s in states), states
    farm.workers = [start_worker(farm.redis_url, f"c-{i}", farm.log_dir) for i in range(3)]
    states = [wait_for_job(farm, job_id, timeout=240, processes=farm.workers)["state"]
              for job_id in ids]
    assert all(s == "done" for s in states), states
    for job_id, form in zip(ids, forms):
        assert_bit_identical(farm_image(farm, job_id, tmp_path), local_reference(form),
                             f"seed {form['seed']}")
    assert int(redis_client.hget(rdb.STATS, "reclaimed") or 0) > reclaimed_before
    # No render process outlived its killed worker (they die with their parent).
    assert orphans
    deadline = time.monotonic() + 10
    while alive := [pid for pid in orphans if is_running(pid)]:
        assert time.monotonic() < deadline, f"render processes {alive} outlived their worker"
        time.sleep(0.05)
    for w in farm.workers:
        assert w.alive(), w.log()


def test_fifty_jobs_submitted_at_once(farm):
    """Fifty concurrent submissions all succeed; GET /jobs/{id} stays responsive while they
    run (latencies printed, not asserted: a test does not time the machine)."""
    form = dict(width=16, height=16, spp=4, max_depth=8, tile_size=16)

    def one(_):
        with open(CORNELL, "rb") as f:
            return httpx.post(f"{farm.base_url}/jobs", files={"file": (CORNELL.name, f)},
                              data={k: str(v) for k, v in form.items()}, timeout=120)

    probe = submit(farm, CORNELL, **form).json()["id"]
    latencies: list[float] = []
    stop = threading.Event()

    def poll_status():
        # Measured throughout: while the fifty uploads arrive and while they render.
        with httpx.Client(base_url=farm.base_url, timeout=60) as client:
            while not stop.is_set():
                t = time.perf_counter()
                assert client.get(f"/jobs/{probe}").status_code == 200
                latencies.append(time.perf_counter() - t)
                time.sleep(0.01)

    poller = threading.Thread(target=poll_status, daemon=True)
    poller.start()
    try:
        with ThreadPoolExecutor(max_workers=50) as pool:
            responses = list(pool.map(one, range(50)))
        assert [r.status_code for r in responses] == [201] * 50, \
            [r.text for r in responses if r.status_code != 201]
        ids = [r.json()["id"] for r in responses]
        for job_id in ids:
            assert wait_for_job(farm, job_id, timeout=180)["state"] == "done"
    finally:
        stop.set()
        poller.join(timeout=60)
    latencies.sort()
    assert len(latencies) >= 5, latencies
    p50, p95 = statistics.median(latencies), latencies[int(0.95 * (len(latencies) - 1))]
    print(f"status latency under load: p50 {p50 * 1000:.1f} ms, p95 {p95 * 1000:.1f} ms, "
          f"max {latencies[-1] * 1000:.1f} ms over {len(latencies)} requests")
    listed = farm.get("/jobs", params={"limit": 1000}).json()["jobs"]
    assert set(ids) <= {j["id"] for j in listed}


def test_submit_cli_waits_and_downloads_the_local_image(farm, tmp_path):
    out = tmp_path / "farm.exr"
    args = ["--res", "40x24", "--spp", "8", "--seed", "9", "--max-depth", "8", "--tile", "16"]
    proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(CORNELL),
                           "--server", str(farm.base_url), "--wait", "-o", str(out), *args],
                          env=clean_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    job_id = proc.stdout.strip()
    assert len(job_id) == 32 and f"wrote {out}" in proc.stderr
    local = tmp_path / "local.exr"
    proc = subprocess.run([sys.executable, "-m", "tessera", "render", str(CORNELL), "-o", str(local),
                           "-q", "--threads", "1", *args],
                          env=clean_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert_bit_identical(images.read_exr(out), images.read_exr(local))
    # A refused job is a clear error, not a traceback.
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n(((( nope")
    proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(bad),
                           "--server", str(farm.base_url)], env=clean_env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "the server refused the job (422)" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(CORNELL),
                           "--server", f"http://127.0.0.1:{free_port()}"], env=clean_env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "cannot talk to" in proc.stderr


def test_restarting_redis_api_and_all_workers_loses_nothing(tmp_path):
    """Redis with the shipped ACL (redis_acl: deploy/users.acl's rules) and an fsynced
    append-only file is SIGKILLed and restarted mid-job, then the API, then every worker:
    no accepted job and no finished tile is lost, /healthz answers 200 while the jobs run,
    and the images equal the local render. Then Redis is restarted gracefully: the finished
    jobs and their images are still there. (With the ACL shipped before, whose default user
    could not replay MULTI/EXEC, the first restart lost every job.)"""
    form = dict(width=64, height=64, spp=128, seed=7, max_depth=16, tile_size=16)  # 16 tiles
    data = tmp_path / "redis-data"
    data.mkdir()
    port = free_port()
    credentials = Credentials.generate()
    restart = dict(port=port, appendonly=True, credentials=credentials)
    with ExitStack() as stack:
        first = stack.enter_context(local_redis(str(data), **restart))
        url, worker_url = first.url, first.worker_url
        api, base = start_api(url, tmp_path)
        stack.callback(lambda: api.stop())
        workers = [start_worker(worker_url, f"r-{i}", tmp_path) for i in range(2)]
        stack.callback(lambda: [w.stop() for w in workers])
        client = stack.enter_context(httpx.Client(base_url=base, timeout=60))
        ids = []
        for _ in range(3):
            r = submit(client, CORNELL, **form)
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
        # A long job behind them (priority 0: the three go first) keeps the farm busy
        # through every restart, however fast the three finish on this machine: the probe
        # is checked while a job runs, not while the farm happens to be idle.
        r = submit(client, CORNELL, **{**form, "spp": 65536, "priority": 0})
        assert r.status_code == 201, r.text
        keeper = r.json()["id"]
        rc = redis.Redis.from_url(url)
        deadline = time.monotonic() + 120
        while sum(rc.hlen(rdb.job_tiles_key(j)) for j in ids) < 3:
            assert time.monotonic() < deadline, "no tiles finished"
            time.sleep(0.02)
        stored = {j: set(rc.hkeys(rdb.job_tiles_key(j))) for j in ids}
        rc.close()

        # 1. Redis dies (SIGKILL, no chance to flush anything more) and comes back.
        first.process.kill()
        first.process.wait()
        second = stack.enter_context(local_redis(str(data), **restart))
        rc = stack.enter_context(redis.Redis.from_url(url))
        for job_id in ids:
            assert rc.exists(rdb.job_key(job_id)), "an accepted job was lost"
            assert stored[job_id] <= set(rc.hkeys(rdb.job_tiles_key(job_id))), \
                "a finished tile was lost"

        # 2. The API dies and a new one takes over; its probe answers while jobs run.
        os.kill(api.pid, signal.SIGKILL)
        api.popen.wait()
        api, base = start_api(url, tmp_path)
        client = stack.enter_context(httpx.Client(base_url=base, timeout=60))
        assert all(client.get(f"/jobs/{j}").status_code == 200 for j in ids)
        assert client.get(f"/jobs/{keeper}").json()["state"] in ("queued", "running")
        r = client.get("/healthz")
        assert r.status_code == 200, r.text

        # 3. Every worker dies mid-job; new ones finish (taking over the dead ones' tiles).
        for w in workers:
            os.kill(w.pid, signal.SIGKILL)
            w.popen.wait()
        workers[:] = [start_worker(worker_url, f"r-new-{i}", tmp_path) for i in range(2)]
        expected = local_reference(form)
        for job_id in ids:
            status = wait_for_job(client, job_id, timeout=180, processes=[api, *workers], expect="done")
            assert status["tiles_done"] == 16
            assert_bit_identical(farm_image(client, job_id, tmp_path), expected, job_id)
        assert client.delete(f"/jobs/{keeper}").status_code < 300

        # 4. A graceful restart of Redis (SIGTERM: it fsyncs and exits): nothing is lost.
        stop_processes([second.process], 10.0)
        stack.enter_context(local_redis(str(data), **restart))
        for job_id in ids:
            r = client.get(f"/jobs/{job_id}")
            assert r.status_code == 200 and r.json()["state"] == "done", r.text
            assert_bit_identical(farm_image(client, job_id, tmp_path), expected, job_id)
    assert "NOPERM" not in (data / "redis.log").read_text(errors="replace")
