"""vcm on the farm (real redis-server, API and worker processes): each iteration's light
vertices are one scene task whose product (the light-vertex grid) every tile pass of the
iteration reads, and the image equals the local render bit for bit,

- with two workers sharing the tiles,
- and after the only worker is SIGKILLed in the middle of an iteration: it hangs (fault
  injection) in a tile task of the first iteration, after that iteration's scene task and
  other tiles are done, so the kill is known to land mid-iteration; a second worker
  reclaims the task and renders the rest.
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
from tessera_base import protocol
from tessera_queue import redis_schema as rdb
from tessera_queue import tasks as queue_tasks
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene

pytestmark = pytest.mark.slow

# Three iterations (passes of 1, 1 and 2 samples), 4 tiles each.
FORM = dict(width=32, height=32, tile_size=16, seed=5, max_depth=6, target_error=1e-6, min_spp=1,
            max_spp=4, integrator="vcm")
PARAMS = {"light_paths": 20000, "radius": 0.05}
ITERATIONS = 3
VICTIM_TILE = 2


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    with api_client(redis_server, tmp_path_factory.mktemp("vcm-farm")) as client:
        yield client


@pytest.fixture(scope="module")
def expected() -> np.ndarray:
    settings = RenderSettings(**FORM, integrator_params=PARAMS)
    return local.render_image(load_scene(str(CORNELL)), settings, progress=False, variance=False).rgba


def submit_job(farm, scene) -> str:
    r = submit(farm, scene, **FORM, integrator_params=json.dumps(PARAMS))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    assert np.array_equal(actual.view(np.uint32), expected.view(np.uint32)), \
        f"{np.count_nonzero(actual != expected)} values differ"


def test_farm_vcm_image_equals_local(farm, redis_client, tmp_path, expected):
    workers = [start_worker(farm.redis_url, f"vcm-{i}", farm.log_dir) for i in range(2)]
    try:
        job = submit_job(farm, CORNELL)
        status = wait_for_job(farm, job, timeout=180, processes=workers, expect="done")
        assert_bit_identical(farm_image(farm, job, tmp_path), expected)
        fields = redis_client.hgetall(rdb.job_key(job))
        assert int(fields[b"scene_passes_stored"]) == ITERATIONS
        digests = {fields[rdb.product_field(p).encode()] for p in range(ITERATIONS)}
        assert len(digests) == ITERATIONS  # fresh light paths and a smaller radius each iteration
        # Each product went with its pass's barrier: Redis holds at most the current one.
        assert redis_client.hlen(rdb.job_products_key(job)) == 0
        # Not vacuous: merging is part of the image (without it, it is bdpt's).
        off = RenderSettings(**FORM, integrator_params={**PARAMS, "merging": 0})
        assert not np.array_equal(
            local.render_image(load_scene(str(CORNELL)), off, progress=False, variance=False).rgba, expected)
    finally:
        for w in workers:
            w.stop()


def test_a_worker_killed_mid_iteration_leaves_the_image_unchanged(farm, redis_client, tmp_path, expected):
    scene = tmp_path / "vcmkill.usda"
    shutil.copy(CORNELL, scene)
    victim = start_worker(farm.redis_url, "vcm-victim", farm.log_dir, faults=f"hang:vcmkill*.usda#{VICTIM_TILE}")
    job = submit_job(farm, scene)
    queue = rdb.job_queue_key(job)
    deadline = time.monotonic() + 90

    def held_task():
        pending = redis_client.xpending_range(queue, rdb.WORKER_GROUP, "-", "+", 1, consumername="vcm-victim")
        if not pending:
            return None
        entries = redis_client.xrange(queue, pending[0]["message_id"], pending[0]["message_id"])
        return queue_tasks.TileTask.from_fields(entries[0][1]) if entries else None

    # The victim runs iteration 0's scene task and tiles until it takes tile VICTIM_TILE,
    # where it hangs (its render process sleeps forever).
    while True:
        task = held_task()
        if task is not None and not task.scene_pass and task.tile.index == VICTIM_TILE and child_pids(victim.pid):
            break
        assert time.monotonic() < deadline, "the victim never hung in its tile\n" + victim.log()
        time.sleep(0.01)
    assert task.pass_index == 0
    fields = redis_client.hgetall(rdb.job_key(job))
    assert int(fields[b"scene_passes_stored"]) == 1  # mid-iteration: its product is stored
    os.kill(victim.pid, signal.SIGKILL)
    victim.popen.wait(timeout=10)
    victim.stop()
    rescuer = start_worker(farm.redis_url, "vcm-rescuer", farm.log_dir)
    try:
        status = wait_for_job(farm, job, timeout=180, processes=[rescuer], expect="done")
        assert_bit_identical(farm_image(farm, job, tmp_path), expected)
    finally:
        rescuer.stop()


def test_a_late_duplicate_whose_pass_is_decided_is_dropped_not_failed(farm, redis_client):
    """decide_pass.lua deletes a pass's product with its barrier. A duplicate tile task of
    that pass that slipped past the worker's stored-tile check (its twin stored the tile
    meanwhile) then finds no product: the worker drops it, since its pass is complete,
    where a missing product of an undecided pass still fails the job (the control)."""
    from tessera_worker.child import Abandoned, RenderFailed
    from tessera_worker.settings import WorkerSettings
    from tessera_worker.worker import Worker

    job = "late-duplicate"
    redis_client.hset(rdb.job_key(job), mapping={"decided_pass": 1, rdb.product_field(1): "ab" * 32})
    try:
        task = queue_tasks.TileTask(job_id=job, scene_hash="0" * 64, scene_name="cornell.usda",
                                    settings=RenderSettings(**FORM, integrator_params=PARAMS),
                                    tile=protocol.tile_grid(32, 32, 16)[0], pass_index=1)
        worker = Worker(WorkerSettings(redis_url=farm.redis_url), name="late-duplicate")
        with pytest.raises(Abandoned, match="pass 1 is complete"):
            worker._scene_product(task)
        with pytest.raises(RenderFailed, match="product is missing"):
            worker._scene_product(task.model_copy(update={"pass_index": 2}))
    finally:
        redis_client.delete(rdb.job_key(job))
