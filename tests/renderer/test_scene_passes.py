"""Scene-wide passes on the farm (real redis-server, API and worker processes), with
photon_direct, whose scene pass traces a batch of photons per iteration:

- the farm's image equals the local render bit for bit (both run tessera_base.film's one
  scene-pass function and one tile-pass function);
- each iteration's product is computed once and stored once (counted by the job hash and,
  locally, by wrapping the function), and the iteration's tiles read it;
- a worker SIGKILLed while it holds a scene task (fault injection makes it hang there, so
  the kill is known to land in the task) has the task reclaimed by another worker, and
  the image is still the local one;
- an integrator's own settings (`integrator_params`) go through the API form into every
  tile: the farm's ao image with a short reach is the local one with that reach.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import time

import numpy as np
import pytest

from conftest import CORNELL, api_client, child_pids, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base.protocol import RenderSettings, tile_grid
from tessera_queue import redis_schema as rdb
from tessera_queue import tasks as queue_tasks
from tessera_renderer import load_scene

# Three iterations: passes of 1, 1 and 2 samples (a noise target no image reaches stops
# at max_spp), 4 tiles each.
FORM = dict(width=32, height=32, tile_size=16, seed=3, max_depth=8, target_error=1e-6, min_spp=1,
            max_spp=4, integrator="photon_direct")
PARAMS = {"photons": 20000, "radius": 30.0}
ITERATIONS = 3


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    with api_client(redis_server, tmp_path_factory.mktemp("scene-passes")) as client:
        yield client


def local_image(form: dict, params: dict, counter: list | None = None) -> np.ndarray:
    settings = RenderSettings(**form, integrator_params=params)
    scene = load_scene(str(CORNELL))
    if counter is None:
        return local.render_image(scene, settings, progress=False, variance=False).rgba
    original = local.run_scene_pass

    def counted(scene, settings, iteration, **kw):
        counter.append(iteration)
        return original(scene, settings, iteration, **kw)

    local.run_scene_pass = counted
    try:
        return local.render_image(scene, settings, progress=False, variance=False).rgba
    finally:
        local.run_scene_pass = original


def submit_job(farm, scene, form: dict, params: dict) -> str:
    r = submit(farm, scene, **form, integrator_params=json.dumps(params))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    assert np.array_equal(actual.view(np.uint32), expected.view(np.uint32)), \
        f"{np.count_nonzero(actual != expected)} values differ"


def test_farm_image_equals_local_and_each_product_is_computed_once(farm, redis_client, tmp_path):
    # A long heartbeat: the counts below assume no task is reclaimed from a live but
    # briefly starved worker, which a 2 s heartbeat allows on a loaded machine.
    workers = [start_worker(farm.redis_url, f"sp-{i}", farm.log_dir, heartbeat_ttl=10.0)
               for i in range(2)]
    try:
        job = submit_job(farm, CORNELL, FORM, PARAMS)
        status = wait_for_job(farm, job, timeout=120, processes=workers, expect="done")
        calls: list[int] = []
        expected = local_image(FORM, PARAMS, calls)
        assert_bit_identical(farm_image(farm, job, tmp_path), expected)
        # One product per iteration, locally and on the farm, and the farm computed each
        # exactly once (no worker died, so nothing was delivered twice).
        assert calls == list(range(ITERATIONS))
        fields = redis_client.hgetall(rdb.job_key(job))
        assert int(fields[b"scene_passes_stored"]) == ITERATIONS
        assert int(fields[b"scene_pass_runs"]) == ITERATIONS
        digests = {fields[rdb.product_field(p).encode()] for p in range(ITERATIONS)}
        assert len(digests) == ITERATIONS  # every iteration has photons of its own
        # Each product went with its pass's barrier (decide_pass.lua): none is left.
        assert redis_client.hlen(rdb.job_products_key(job)) == 0
        # Progress and the lockstep barriers count the grid's tiles (a scene-pass job starts
        # with one scene task, which once made tiles_total 1: a barrier after every tile
        # pass, all but the last dropped, and progress of "1 tile").
        tiles = len(tile_grid(FORM["width"], FORM["height"], FORM["tile_size"]))
        assert int(fields[b"tiles_total"]) == tiles == status["tiles_total"] == 4
        assert int(fields[b"lockstep_tiles"]) == tiles * ITERATIONS
        # The scene pass matters: another photon count is another image.
        other = local_image(FORM, {**PARAMS, "photons": 10000})
        assert not np.array_equal(other, expected)
    finally:
        for w in workers:
            w.stop()


def test_a_worker_killed_in_a_scene_task_has_it_reclaimed(farm, redis_client, tmp_path):
    scene = tmp_path / "scenekill.usda"
    shutil.copy(CORNELL, scene)
    reclaimed_before = int(redis_client.hget(rdb.STATS, "reclaimed") or 0)
    # The only worker: it takes the first scene task and hangs in it.
    victim = start_worker(farm.redis_url, "sp-victim", farm.log_dir, faults="hang:scenekill*.usda#scene")
    job = submit_job(farm, scene, FORM, PARAMS)
    queue = rdb.job_queue_key(job)
    deadline = time.monotonic() + 60
    while not redis_client.xpending_range(queue, rdb.WORKER_GROUP, "-", "+", 1, consumername="sp-victim"):
        assert time.monotonic() < deadline, "the victim never took the scene task\n" + victim.log()
        time.sleep(0.01)
    pending = redis_client.xrange(queue)
    assert [queue_tasks.TileTask.from_fields(f).scene_pass for _, f in pending] == [True]
    while not child_pids(victim.pid):  # its render process, hanging in the scene task
        assert time.monotonic() < deadline, "the victim has no render process\n" + victim.log()
        time.sleep(0.01)
    os.kill(victim.pid, signal.SIGKILL)
    victim.popen.wait(timeout=10)
    victim.stop()
    assert redis_client.hget(rdb.job_key(job), "scene_passes_stored") is None  # nothing stored
    rescuer = start_worker(farm.redis_url, "sp-rescuer", farm.log_dir)
    try:
        status = wait_for_job(farm, job, timeout=120, processes=[rescuer], expect="done")
        assert int(redis_client.hget(rdb.STATS, "reclaimed") or 0) > reclaimed_before
        fields = redis_client.hgetall(rdb.job_key(job))
        assert int(fields[b"scene_passes_stored"]) == ITERATIONS
        assert int(fields[b"scene_pass_runs"]) == ITERATIONS  # the victim finished none
        assert_bit_identical(farm_image(farm, job, tmp_path), local_image(FORM, PARAMS))
    finally:
        rescuer.stop()


def test_integrator_params_reach_every_tile_through_the_api(farm, tmp_path):
    form = dict(width=32, height=32, tile_size=16, spp=4, seed=1, integrator="ao")
    r = submit(farm, CORNELL, **form, integrator_params=json.dumps({"reach": 1}))
    assert r.status_code == 422 and "has no setting 'reach'" in r.text, r.text
    r = submit(farm, CORNELL, **form, integrator_params="[1]")
    assert r.status_code == 422 and "JSON object" in r.text, r.text
    worker = start_worker(farm.redis_url, "sp-ao", farm.log_dir)
    try:
        job = submit_job(farm, CORNELL, form, {"max_distance": 0.05})
        assert wait_for_job(farm, job, processes=[worker])["state"] == "done"
        near = local_image(form, {"max_distance": 0.05})
        assert_bit_identical(farm_image(farm, job, tmp_path), near)
        assert not np.array_equal(near, local_image(form, {}))
    finally:
        worker.stop()


def test_a_product_delivered_twice_is_stored_and_its_tiles_queued_once(redis_client):
    """A scene task computed twice (its first worker died after computing, before its
    ack) arrives twice with the same bytes: the second is only acknowledged. Run against
    the worker's own script on a real Redis (the job paused, so that no worker of the
    session picks its fake tasks)."""
    scripts = rdb.Scripts(redis_client)
    job = "product-once"
    keys = rdb.job_script_keys(job, "no-scene")
    key, queue = rdb.job_key(job), rdb.job_queue_key(job)
    redis_client.delete(*rdb.job_keys(job))
    redis_client.hset(key, mapping={"state": "paused", "tiles_total": 2, "priority": 5})
    redis_client.xgroup_create(queue, rdb.WORKER_GROUP, id="0", mkstream=True)
    first = redis_client.xadd(queue, {"task": "scene"})
    args = [job, 0, "d1g35t", b"photons", first, repr(time.time()), "w-1", "0.25", "t0", "t1"]
    assert scripts.store_product(keys=keys, args=args) == 1
    again = redis_client.xadd(queue, {"task": "scene"})
    assert scripts.store_product(keys=keys, args=[*args[:4], again, *args[5:]]) == 0
    assert [f[b"task"] for _, f in redis_client.xrange(queue)] == [b"t0", b"t1"]
    assert redis_client.hget(key, rdb.product_field(0)) == b"d1g35t"
    assert redis_client.hget(key, "scene_passes_stored") == b"1"
    assert redis_client.hgetall(rdb.job_products_key(job)) == {b"d1g35t": b"photons"}
    stored = [rdb.JobEvent.from_fields(f) for _, f in redis_client.xrange(rdb.job_events_key(job))]
    assert [(e.type, e.pass_index, e.worker, e.seconds) for e in stored] == [("scene_pass", 0, "w-1", 0.25)]
    # A final job takes no product.
    redis_client.hset(key, "state", "cancelled")
    late = redis_client.xadd(queue, {"task": "scene"})
    assert scripts.store_product(keys=keys, args=[job, 1, "x", b"y", late, repr(time.time()), "w-1", "1"]) == -1
    assert redis_client.hget(key, rdb.product_field(1)) is None
    redis_client.delete(*rdb.job_keys(job))
