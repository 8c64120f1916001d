"""Job lifecycle on a real farm, proven by fault injection: renderer crashes, poison tiles,
time and memory limits, blocklisting, cancel, pause/resume, priorities and fair share,
progress events, the job log, /workers, /metrics, previews, noise-target passes, auth.

The workers' render processes are made to crash on purpose through their
TESSERA_WORKER_FAULTS rules (see docs/farm.md): a scene named poison*.usda segfaults on
tile 1 everywhere, hang*.usda never finishes, oom*.usda allocates without bound, and on
worker "w-y" only, blocky*.usda segfaults on every tile."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest
import redis

from conftest import (CORNELL, STARTUP_TIMEOUT, child_pids, clean_env, is_running, farm_image, local_reference, start_api, start_worker,
                      submit, wait_for_job)
from tessera_base import protocol
from tessera_base import convergence
from tessera_queue import redis_schema as rdb
from tessera_worker.worker import CLAIM_MIN_IDLE_MS
from tessera_cli.embedded import free_port, redis_server as local_redis

COMMON_FAULTS = "segv:poison*.usda#1,hang:hang*.usda,oom:oom*.usda"
TILE_TIMEOUT = 6.0
MEMORY_LIMIT = 6 << 30


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("lifecycle")
    api_proc, base = start_api(redis_server, logs)
    workers = {
        "w-x": start_worker(redis_server, "w-x", logs, faults=COMMON_FAULTS,
                            tile_timeout=TILE_TIMEOUT, memory_limit=MEMORY_LIMIT),
        "w-y": start_worker(redis_server, "w-y", logs, faults=COMMON_FAULTS + ",segv:blocky*.usda",
                            tile_timeout=TILE_TIMEOUT, memory_limit=MEMORY_LIMIT),
    }
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes = [api_proc, *workers.values()]
        client.workers = workers
        client.redis_url = redis_server
        yield client
    for proc in [*workers.values(), api_proc]:
        proc.stop()


def scene_named(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    shutil.copy(CORNELL, path)
    return path




def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    differ = actual.view(np.uint32) != expected.view(np.uint32)
    assert not differ.any(), f"{int(differ.sum())} of {differ.size} values differ"


def assert_farm_alive(farm) -> None:
    assert all(p.alive() for p in farm.processes), "\n".join(p.log() for p in farm.processes)


def wait_until(predicate, timeout: float, message: str, interval: float = 0.05):
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, message
        time.sleep(interval)
    return value


# ------------------------------------------------------------------ crash isolation
def test_segfaulting_tile_is_retried_then_poisons_only_its_job(farm, redis_client, tmp_path):
    small = dict(width=32, height=32, spp=2, max_depth=8, tile_size=16)
    poison = submit(farm, scene_named(tmp_path, "poison.usda"), **small)
    healthy = submit(farm, CORNELL, **small)
    assert poison.status_code == healthy.status_code == 201
    status = wait_for_job(farm, poison.json()["id"], processes=farm.processes)
    assert status["state"] == "failed", status
    assert status["error"].startswith(f"tile 1 failed {protocol.DEFAULT_MAX_ATTEMPTS} times")
    assert "the renderer crashed (SIGSEGV)" in status["error"]
    # The other job is unaffected, and so are the workers (only their render child died).
    assert wait_for_job(farm, healthy.json()["id"], processes=farm.processes)["state"] == "done"
    assert_farm_alive(farm)
    dead = redis_client.xrange(rdb.DEAD_LETTER)
    assert any(f[b"job"].decode() == poison.json()["id"] and f[b"tile"] == b"1" for _, f in dead)
    log = farm.get(f"/jobs/{poison.json()['id']}/log").json()["lines"]
    assert sum("tile 1 attempt" in line and "SIGSEGV" in line for line in log) == 3, log
    # The job may set its own budget of attempts.
    once = submit(farm, scene_named(tmp_path, "poison.usda"), max_attempts=1, **small)
    assert once.status_code == 201, once.text
    status = wait_for_job(farm, once.json()["id"], processes=farm.processes)
    assert status["state"] == "failed" and status["error"].startswith("tile 1 failed 1 times"), status
    bad = submit(farm, CORNELL, max_attempts=0, **small)
    assert bad.status_code == 422 and "max_attempts" in bad.text


def test_time_limit_fails_the_job_and_a_slow_tile_is_never_stolen(farm, redis_client, tmp_path):
    """Both workers hang on a tile. While they do, an idle third worker's reaper looks at the
    tiles after they have been idle longer than a claim needs, and leaves them with their
    live workers (delivered once); then the job fails naming the limit, and the workers go
    on."""
    reclaimed = int(redis_client.hget(rdb.STATS, "reclaimed") or 0)
    reaper = start_worker(farm.redis_url, "w-z", tmp_path, tile_timeout=TILE_TIMEOUT)
    try:
        r = submit(farm, scene_named(tmp_path, "hang.usda"), width=16, height=16, spp=1, tile_size=8)
        assert r.status_code == 201
        job_id = r.json()["id"]
        queue = rdb.job_queue_key(job_id)
        hung = {"w-x", "w-y"}

        def held_by_hung():
            entries = redis_client.xpending_range(queue, rdb.WORKER_GROUP, "-", "+", 10)
            return [e for e in entries if e["consumer"].decode() in hung]

        held = wait_until(lambda: len(held_by_hung()) == 2, 60, "the hanging workers took no tiles")
        first = {e["message_id"]: e["consumer"] for e in held_by_hung()}
        reaps_seen = None  # w-z's reap count once both tiles could have been claimed
        while redis_client.exists(queue):
            entries = held_by_hung()
            for e in entries:
                assert e["times_delivered"] == 1, e
                assert e["consumer"] == first.get(e["message_id"], e["consumer"]), e
            reaps = int(redis_client.hget(rdb.worker_key("w-z"), "reaps") or 0)
            if len(entries) == 2 and all(e["time_since_delivered"] > 2 * CLAIM_MIN_IDLE_MS
                                         for e in entries):
                reaps_seen = reaps_seen if reaps_seen is not None else reaps
                if reaps > reaps_seen:
                    break  # a reaper ran while it could have stolen both tiles, and did not
            time.sleep(0.05)
        assert reaps_seen is not None and reaps > reaps_seen, \
            "the job ended before a reaper looked at its idle tiles\n" + reaper.log()
    finally:
        reaper.stop()
    status = wait_for_job(farm, job_id, timeout=60 + 2 * TILE_TIMEOUT, processes=farm.processes)
    assert status["state"] == "failed", status
    assert f"exceeded the per-tile time limit of {TILE_TIMEOUT:g} s" in status["error"]
    assert "of 'hang.usda'" in status["error"]
    assert int(redis_client.hget(rdb.STATS, "reclaimed") or 0) == reclaimed
    assert_farm_alive(farm)


def test_memory_limit_fails_the_job_with_a_clear_message(farm, tmp_path):
    r = submit(farm, scene_named(tmp_path, "oom.usda"), width=16, height=16, spp=1, tile_size=8)
    assert r.status_code == 201
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes)
    assert status["state"] == "failed", status
    assert "exceeded the worker's memory limit of 6 GiB" in status["error"], status
    assert_farm_alive(farm)


def test_worker_that_keeps_failing_a_job_is_blocklisted(farm, tmp_path):
    # 64 tiles, several seconds of work: w-y's render process needs a moment to restart
    # after each crash, and must still find tiles to fail on.
    form = dict(width=128, height=128, spp=384, seed=1, max_depth=8, tile_size=16)
    r = submit(farm, scene_named(tmp_path, "blocky.usda"), **form)
    assert r.status_code == 201
    job_id = r.json()["id"]
    status = wait_for_job(farm, job_id, processes=farm.processes, expect="done")
    log = farm.get(f"/jobs/{job_id}/log").json()["lines"]
    assert any("worker w-y is blocklisted for this job" in line for line in log), log
    # w-y crashed exactly until it was blocklisted; w-x rendered everything correctly.
    assert sum("failed on worker w-y" in line for line in log) == protocol.BLOCKLIST_AFTER
    assert not any("failed on worker w-x" in line for line in log)
    assert_bit_identical(farm_image(farm, job_id, tmp_path), local_reference(form))
    workers = {w["name"]: w for w in farm.get("/workers").json()["workers"]}
    assert workers["w-y"]["failures"] >= protocol.BLOCKLIST_AFTER
    assert_farm_alive(farm)


# ------------------------------------------------------------------ cancel, pause
def test_cancel_stops_outstanding_work_promptly(farm, redis_client):
    """Cancelling drops the queued tiles at once and abandons the tiles being rendered
    (their render processes are killed): nothing of the job is stored afterwards."""
    r = submit(farm, CORNELL, width=64, height=64, spp=4096, max_depth=16, tile_size=32)
    job_id = r.json()["id"]  # four tiles of several seconds each

    def both_rendering():
        current = [w["current"] or "" for w in farm.get("/workers").json()["workers"]]
        return len(current) == 2 and all(c.startswith(job_id) for c in current)

    wait_until(both_rendering, 60, "the workers never both rendered the job")
    stored = redis_client.hlen(rdb.job_tiles_key(job_id))
    assert farm.delete(f"/jobs/{job_id}").json()["state"] == "cancelled"
    assert not redis_client.exists(rdb.job_queue_key(job_id))
    for name, proc in farm.workers.items():
        wait_until(lambda: f"job {job_id} ended while tile" in proc.log(400), 30,
                   f"{name} did not abandon its tile\n" + proc.log())
    assert redis_client.hlen(rdb.job_tiles_key(job_id)) == stored
    events = farm.get(f"/jobs/{job_id}/events").text
    assert '"state": "cancelled"' in events
    assert_farm_alive(farm)


def test_pause_and_resume(farm, redis_client, tmp_path):
    form = dict(width=64, height=64, spp=16, seed=2, max_depth=8, tile_size=8)  # 64 tiles
    r = submit(farm, CORNELL, **form)
    job_id = r.json()["id"]
    assert farm.post(f"/jobs/{job_id}/pause").json()["state"] == "paused"
    assert redis_client.zscore(rdb.READY, job_id) is None
    # Whatever was picked before the pause is stored; then nothing more is served.
    queue = rdb.job_queue_key(job_id)
    wait_until(lambda: redis_client.xpending(queue, rdb.WORKER_GROUP)["pending"] == 0,
               30, "tiles picked before the pause were not finished")
    before = farm.get(f"/jobs/{job_id}").json()
    assert before["state"] == "paused" and before["tiles_done"] < 64
    assert redis_client.xlen(queue) == 64 - before["tiles_done"]
    assert farm.post(f"/jobs/{job_id}/resume").json()["state"] in ("queued", "running")
    status = wait_for_job(farm, job_id, processes=farm.processes)
    assert status["state"] == "done"
    assert_bit_identical(farm_image(farm, job_id, tmp_path), local_reference(form))
    # Pausing a finished job leaves it as it is.
    assert farm.post(f"/jobs/{job_id}/pause").json()["state"] == "done"
    assert farm.post("/jobs/nope/pause").status_code == 404


# ------------------------------------------------------------------ progress
def test_events_stream_tiles_and_states(farm):
    r = submit(farm, CORNELL, width=32, height=32, spp=2, max_depth=8, tile_size=16)
    job_id = r.json()["id"]
    events = []
    with farm.stream("GET", f"/jobs/{job_id}/events") as response:
        assert response.status_code == 200
        assert response.headers["content-type"].startswith("text/event-stream")
        current = {}
        for line in response.iter_lines():
            if line.startswith("id: "):
                current = {"id": line[4:]}
            elif line.startswith("data: "):
                current["data"] = json.loads(line[6:])
                events.append(current)
    types = [e["data"]["type"] for e in events]
    states = [e["data"]["state"] for e in events if e["data"]["type"] == "state"]
    assert states == ["queued", "running", "done"], events
    tiles = [e["data"] for e in events if e["data"]["type"] == "tile"]
    assert sorted(t["tile"] for t in tiles) == [0, 1, 2, 3]
    assert [t["tiles_done"] for t in tiles] == [1, 2, 3, 4]
    assert types[-1] == "state"
    # Resuming after an event id gives only what came after it.
    r = farm.get(f"/jobs/{job_id}/events", params={"after": events[-2]["id"]})
    assert r.text.count("data: ") == 1 and '"done"' in r.text


def test_preview_while_running_list_workers_and_metrics(farm, redis_client):
    r = submit(farm, CORNELL, width=96, height=96, spp=64, max_depth=16, tile_size=16,
               priority=7)
    job_id = r.json()["id"]
    wait_until(lambda: farm.get(f"/jobs/{job_id}").json()["tiles_done"] >= 2, 60,
               "no tile finished")
    preview = farm.get(f"/jobs/{job_id}/preview.png")
    assert preview.status_code == 200 and preview.content.startswith(b"\x89PNG")
    metrics = farm.get("/metrics")
    assert metrics.status_code == 200
    text = metrics.text
    depth = [line for line in text.splitlines() if line.startswith('tessera_queue_depth{priority="7"}')]
    assert depth and float(depth[0].split()[-1]) > 0, text
    for name in ("tessera_tiles_total", "tessera_render_seconds_total",
                 "tessera_tile_failures_total", "tessera_tiles_reclaimed_total", "tessera_workers "):
        assert name in text, name
    workers = farm.get("/workers").json()["workers"]
    assert {w["name"] for w in workers} == {"w-x", "w-y"}
    assert all(w["tiles_done"] > 0 for w in workers)
    status = wait_for_job(farm, job_id, processes=farm.processes)
    assert status["state"] == "done" and status["priority"] == 7
    listed = farm.get("/jobs", params={"state": "done"}).json()["jobs"]
    assert job_id in [j["id"] for j in listed] and all(j["state"] == "done" for j in listed)
    failed = farm.get("/jobs", params={"state": "failed"}).json()["jobs"]
    assert all(j["state"] == "failed" for j in failed)
    assert farm.get("/jobs", params={"state": "exploded"}).status_code == 422


# ------------------------------------------------------------------ noise target
def test_noise_target_passes_equal_the_local_render(farm, redis_client, tmp_path):
    form = dict(width=48, height=48, seed=4, max_depth=8, tile_size=16, target_error=0.2,
                min_spp=4, max_spp=64)
    r = submit(farm, CORNELL, **form)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    status = wait_for_job(farm, job_id, processes=farm.processes, expect="done")
    # Tiles converge unevenly: more passes than tiles, fewer than the full schedule.
    assert 9 < status["passes_done"] < 9 * 5, status
    fields = redis_client.hkeys(rdb.job_tiles_key(job_id))
    assert len(fields) == status["passes_done"]
    assert_bit_identical(farm_image(farm, job_id, tmp_path), local_reference(form))


@pytest.mark.parametrize("integrator", ["bdpt", "light"])
def test_lockstep_noise_target_equals_the_local_render(farm, redis_client, tmp_path, integrator):
    """Splatting integrators reach a noise target pass by pass over the whole image: every
    tile gets the same passes, the barrier stops before the full schedule, and the merged
    image (camera parts and all passes' splats) equals the local render bit for bit."""
    form = dict(width=32, height=32, seed=3, max_depth=6, tile_size=16, target_error=0.15,
                min_spp=2, max_spp=256, integrator=integrator)
    r = submit(farm, CORNELL, **form)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    status = wait_for_job(farm, job_id, processes=farm.processes, expect="done")
    assert status["tiles_done"] == status["tiles_total"] == 4
    fields = {f.decode() for f in redis_client.hkeys(rdb.job_tiles_key(job_id))}
    passes = status["passes_done"] // 4
    assert status["passes_done"] == 4 * passes and passes >= 2, status
    assert fields == {f"{t}:{p}" for t in range(4) for p in range(passes)}
    assert passes < 8, "the target should stop it before max_spp (2..256 is 8 passes)"
    acc = convergence.PassAccumulator.from_bytes(redis_client.get(rdb.job_passes_key(job_id)))
    assert acc.passes == passes and acc.error() <= form["target_error"]
    local = local_reference(form)
    assert_bit_identical(farm_image(farm, job_id, tmp_path), local)


def test_a_pass_barrier_applies_once(redis_client):
    """At-least-once delivery may hand a lockstep barrier out twice (a worker that dies
    after applying it but before its ack): the second application queues nothing and
    leaves the accumulator alone. Run against the worker's own script on a real Redis."""
    scripts = rdb.Scripts(redis_client)
    job = "barrier-once"
    keys = rdb.job_script_keys(job, "no-scene")

    def decide(args):
        return scripts.decide_pass(keys=keys, args=args)
    key, queue = rdb.job_key(job), rdb.job_queue_key(job)
    redis_client.delete(key, queue, rdb.job_passes_key(job))
    # Paused, so that the module's running workers never see this job's fake tasks.
    redis_client.hset(key, mapping={"state": "paused", "tiles_total": 2, "priority": 5})
    redis_client.xgroup_create(queue, rdb.WORKER_GROUP, id="0", mkstream=True)
    entry = redis_client.xadd(queue, {"task": "barrier"})
    args = [job, 0, 0, repr(time.time()), entry, b"acc-after-pass-0", "t0", "t1"]
    assert decide(args=args) == 0
    assert [f[b"task"] for _, f in redis_client.xrange(queue)] == [b"t0", b"t1"]
    again = redis_client.xadd(queue, {"task": "barrier"})
    assert decide(args=[job, 0, 0, repr(time.time()), again, b"other", "t0", "t1"]) == -1
    assert [f[b"task"] for _, f in redis_client.xrange(queue)] == [b"t0", b"t1"]
    assert redis_client.get(rdb.job_passes_key(job)) == b"acc-after-pass-0"
    # The next pass's barrier finishes the job.
    last = redis_client.xadd(queue, {"task": "barrier"})
    assert decide(args=[job, 1, 1, repr(time.time()), last, b"acc-after-pass-1"]) == 1
    assert redis_client.hget(key, "state") == b"done" and redis_client.hget(key, "tiles_done") == b"2"
    redis_client.delete(*rdb.job_keys(job))


# ------------------------------------------------------------------ priorities
def test_priority_first_then_fair_share(tmp_path):
    """One worker, started after four jobs are queued: the priority-9 job is served first,
    the two priority-5 jobs share the worker tile by tile, the priority-1 job comes last."""
    with local_redis(str(tmp_path)) as rs:
        api, base = start_api(rs.url, tmp_path)
        worker = None
        try:
            with httpx.Client(base_url=base, timeout=60) as client:
                # 16 tiles each.
                small = dict(width=32, height=32, spp=64, max_depth=4, tile_size=8)
                ids = {}
                for name, priority in (("low", 1), ("fair-a", 5), ("fair-b", 5), ("high", 9)):
                    r = submit(client, CORNELL, priority=priority, **small)
                    assert r.status_code == 201, r.text
                    ids[name] = r.json()["id"]
                worker = start_worker(rs.url, "solo", tmp_path)
                for job_id in ids.values():
                    assert wait_for_job(client, job_id, processes=[worker])["state"] == "done"
            # The order served is the solo worker's own record of the tiles it rendered, one
            # after another (event ids carry milliseconds and cannot order tiles of two jobs
            # finished within one).
            names = {job_id: name for name, job_id in ids.items()}
            log = worker.log_path.read_text()
            order = [names[job] for job in re.findall(r"job (\S+) tile \d+ pass \d+ rendered", log)]
            assert len(order) == 64, order
            assert order[:16] == ["high"] * 16, order
            assert order[-16:] == ["low"] * 16, order
            fair = order[16:48]
            for k in range(2, 33, 2):  # after every two tiles, each job had one
                assert fair[:k].count("fair-a") == fair[:k].count("fair-b"), fair
        finally:
            if worker:
                worker.stop()
            api.stop()


# ------------------------------------------------------------------ auth
def test_bearer_token_auth(redis_server, tmp_path):
    api, base = start_api(redis_server, tmp_path, api_tokens="s3cret,other")
    try:
        assert httpx.get(f"{base}/healthz").status_code == 200  # probes need no token
        for path in ("/jobs", "/workers", "/metrics", "/jobs/x"):
            r = httpx.get(f"{base}{path}")
            assert r.status_code == 401 and "bearer token" in r.json()["detail"], path
            assert r.headers["www-authenticate"].startswith("Bearer")
        r = httpx.get(f"{base}/jobs", headers={"Authorization": "Bearer wrong"})
        assert r.status_code == 401 and "not valid" in r.json()["detail"]
        for token in ("s3cret", "other"):
            r = httpx.get(f"{base}/jobs", headers={"Authorization": f"Bearer {token}"})
            assert r.status_code == 200, r.text
        schema = httpx.get(f"{base}/openapi.json").json()
        assert "HTTPBearer" in schema["components"]["securitySchemes"]
    finally:
        api.stop()


def test_serve_refuses_to_listen_off_loopback_without_tokens(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tessera", "serve", "--host", "0.0.0.0",
                           "--port", str(free_port()), "--workers", "0"],
                          env=clean_env(REDIS_URL="redis://127.0.0.1:1/0"), capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode != 0
    assert "without authentication" in proc.stderr and "TESSERA_API_TOKENS" in proc.stderr


# ------------------------------------------------------------------ caching, retention
def test_preflight_result_is_cached_by_scene_hash(farm, redis_client, tmp_path):
    import hashlib
    scene = scene_named(tmp_path, "cached.usda")
    scene_hash = hashlib.sha256(scene.read_bytes()).hexdigest()
    r = submit(farm, scene, width=16, height=16, spp=1, tile_size=16)
    assert r.status_code == 201
    cached = json.loads(redis_client.get(rdb.preflight_key(scene_hash, ".usda")))
    assert (cached["width"], cached["height"]) == (512, 512)
    assert 0 < redis_client.ttl(rdb.preflight_key(scene_hash, ".usda"))
    # Proof that the inspection is skipped: a doctored cache entry is believed.
    redis_client.set(rdb.preflight_key(scene_hash, ".usda"),
                     json.dumps({**cached, "width": 24, "height": 8, "warnings": ["cached!"]}))
    r = submit(farm, scene, spp=1, tile_size=8)
    assert r.status_code == 201
    assert (r.json()["width"], r.json()["height"], r.json()["warnings"]) == (24, 8, ["cached!"])
    wait_for_job(farm, r.json()["id"], processes=farm.processes)


def test_finished_jobs_expire(redis_server, redis_client, tmp_path):
    api, base = start_api(redis_server, tmp_path, job_retention=2)
    try:
        with httpx.Client(base_url=base, timeout=60) as client:
            r = submit(client, CORNELL, width=16, height=16, spp=1, tile_size=16)
            job_id = r.json()["id"]
            # Cancelled, or done if a worker was quicker: either way it is final now.
            assert client.delete(f"/jobs/{job_id}").json()["state"] in ("cancelled", "done")
            for key in (rdb.job_key(job_id), rdb.job_events_key(job_id),
                        rdb.job_log_key(job_id)):
                assert 0 < redis_client.pttl(key) <= 2000, key
            wait_until(lambda: not redis_client.exists(rdb.job_key(job_id)), 30,
                       "the job did not expire")
            assert client.get(f"/jobs/{job_id}").status_code == 404
            assert job_id not in [j["id"] for j in client.get("/jobs").json()["jobs"]]
            assert redis_client.zscore(rdb.JOB_INDEX, job_id) is None
    finally:
        api.stop()


def test_a_killed_api_leaves_no_inspection_running_and_its_next_start_removes_the_upload(
        redis_server, tmp_path):
    """The API SIGKILLed while it inspects an upload: the inspection child dies with it
    (it is SIGSTOPped first, so it cannot simply finish: only the parent-death signal can
    end it), and the next API process removes the upload folder the killed one left."""
    import threading

    api, base = start_api(redis_server, tmp_path, preflight_timeout="600")
    scene = tmp_path / "scene.usda"
    # Bytes no earlier test uploaded: a scene inspected before is not inspected again.
    scene.write_text(CORNELL.read_text() + f"\n# {uuid.uuid4().hex}\n")
    threading.Thread(target=lambda: _post_ignoring_errors(base, scene), daemon=True).start()
    deadline = time.monotonic() + STARTUP_TIMEOUT
    while not (inspections := [c for c in child_pids(api.pid) if b"tessera_renderer.inspect" in _cmdline(c)]):
        assert api.alive() and time.monotonic() < deadline, api.log()
        time.sleep(0.01)
    [child] = inspections
    os.kill(child, signal.SIGSTOP)
    uploads = list(Path(tempfile.gettempdir()).glob(f"tessera-upload-{api.pid}-*"))
    assert len(uploads) == 1 and any(uploads[0].iterdir())  # the user's scene is in it
    os.kill(api.pid, signal.SIGKILL)
    api.popen.wait()
    deadline = time.monotonic() + STARTUP_TIMEOUT
    while is_running(child):
        assert time.monotonic() < deadline, f"the inspection {child} outlived the killed API"
        time.sleep(0.01)
    again, _ = start_api(redis_server, tmp_path)
    try:
        assert not uploads[0].exists(), "the killed API's upload folder is still there"
        assert "left by an API process that was killed" in again.log()
    finally:
        again.stop()


def _cmdline(pid: int) -> bytes:
    try:
        return Path("/proc", str(pid), "cmdline").read_bytes()
    except OSError:
        return b""


def _post_ignoring_errors(base: str, scene: Path) -> None:
    try:
        with scene.open("rb") as f:
            httpx.post(f"{base}/jobs", files={"file": (scene.name, f)}, timeout=60)
    except httpx.HTTPError:
        pass  # the API is killed mid-request


def test_a_worker_start_removes_what_killed_workers_left(redis_server, tmp_path):
    """A folder of a dead worker (its pid in the name) is removed when the next worker
    starts; one of a live worker is left alone."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    orphan = Path(tempfile.mkdtemp(prefix=f"tessera-worker-{dead.pid}-"))
    (orphan / "scene.usda").write_text("#usda 1.0\n")
    alive = Path(tempfile.mkdtemp(prefix=f"tessera-worker-{os.getpid()}-"))
    worker = start_worker(redis_server, "w-cleanup", tmp_path)
    try:
        assert not orphan.exists() and alive.exists()
        assert f"removed {orphan}" in worker.log()
    finally:
        worker.stop()
        shutil.rmtree(alive)
