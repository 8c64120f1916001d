"""sppm and photon on the farm (real redis-server, API and worker processes): the farm's
image equals the local render bit for bit, for sppm also when a worker is SIGKILLed in the
middle of an iteration, in its scene task or in one of its tile tasks (fault injection
makes the worker hang there, so the kill is known to land in that task).

The glass-sphere caustic scene, 32 x 32 in 4 tiles, passes of 1, 1, 2 and 4 samples: four
iterations, each a photon pass (sppm's holding 1, 1, 2 and 4 photon batches) and its tile
passes.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import time

import numpy as np
import pytest

from conftest import REPO, api_client, child_pids, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base import protocol
from tessera_queue import redis_schema as rdb
from tessera_queue import tasks as queue_tasks
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene

CAUSTIC = REPO / "examples" / "caustic" / "caustic.usda"
FORM = dict(width=32, height=32, tile_size=16, seed=5, max_depth=8, target_error=1e-6, min_spp=1,
            max_spp=8, integrator="sppm")
PARAMS = {"photons": 20000}
ITERATIONS = 4
pytestmark = pytest.mark.slow  # about a minute: real farms, four iterations each


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    with api_client(redis_server, tmp_path_factory.mktemp("sppm-farm")) as client:
        yield client


def local_image(form: dict, params: dict, scene_path=CAUSTIC) -> np.ndarray:
    settings = RenderSettings(**form, integrator_params=params)
    return local.render_image(load_scene(str(scene_path)), settings, progress=False, variance=False).rgba


def submit_job(farm, scene, form: dict, params: dict) -> str:
    r = submit(farm, scene, **form, integrator_params=json.dumps(params))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    assert np.array_equal(actual.view(np.uint32), expected.view(np.uint32)), \
        f"{np.count_nonzero(actual != expected)} values differ"


def test_the_pass_schedule_is_the_one_sppm_assumes():
    """sppm gives iteration k 2^(k-1) photon batches (1 for k = 0) so that every batch
    carries the same weight in the sample-weighted image: the passes must double."""
    settings = RenderSettings(**FORM)
    sizes = [protocol.pass_range(settings, k)[1] for k in range(ITERATIONS)]
    assert sizes == [1, 1, 2, 4]
    assert protocol.pass_range(settings, ITERATIONS) is None


@pytest.mark.parametrize("integrator,params", [("sppm", PARAMS),
                                               ("photon", {"photons": 5000, "caustic_photons": 20000,
                                                           "gather": 2})])
def test_farm_image_equals_local(farm, redis_client, tmp_path, integrator, params):
    form = {**FORM, "integrator": integrator}
    workers = [start_worker(farm.redis_url, f"sppm-{integrator}-{i}", farm.log_dir) for i in range(2)]
    try:
        job = submit_job(farm, CAUSTIC, form, params)
        status = wait_for_job(farm, job, timeout=180, processes=workers, expect="done")
        expected = local_image(form, params)
        assert_bit_identical(farm_image(farm, job, tmp_path), expected)
        fields = redis_client.hgetall(rdb.job_key(job))
        assert int(fields[b"scene_passes_stored"]) == ITERATIONS
        # Every iteration stored a product, and each went with its pass's barrier.
        assert all(rdb.product_field(k).encode() in fields for k in range(ITERATIONS))
        assert redis_client.hlen(rdb.job_products_key(job)) == 0
        # The photons matter: another photon count is another image.
        other = local_image(form, {**params, "photons": params["photons"] // 2})
        assert not np.array_equal(other, expected)
    finally:
        for w in workers:
            w.stop()


def test_a_fixed_spp_job_runs_every_iteration_and_equals_local(farm, redis_client, tmp_path):
    """A fixed spp of sppm (8 samples) runs the passes of a noise target from one sample,
    1, 1, 2 and 4 (issue 46: it was one pass, one photon batch, and stopped converging): four
    iterations on the farm as locally. The farm's image equals the local one bit for bit, and
    both equal the noise-target render that runs to its max_spp (FORM)."""
    fixed = {k: v for k, v in FORM.items() if k not in ("target_error", "min_spp", "max_spp")}
    fixed["spp"] = 8
    assert RenderSettings(**fixed).lockstep
    workers = [start_worker(farm.redis_url, f"sppm-fixed-{i}", farm.log_dir) for i in range(2)]
    try:
        job = submit_job(farm, CAUSTIC, fixed, PARAMS)
        wait_for_job(farm, job, timeout=180, processes=workers, expect="done")
        expected = local_image(fixed, PARAMS)
        assert_bit_identical(farm_image(farm, job, tmp_path), expected)
        assert int(redis_client.hget(rdb.job_key(job), "scene_passes_stored")) == ITERATIONS
        assert_bit_identical(local_image(FORM, PARAMS), expected)
    finally:
        for w in workers:
            w.stop()


@pytest.mark.parametrize("target", ["scene", "2"])
def test_a_worker_killed_mid_iteration_changes_nothing(farm, redis_client, tmp_path, target):
    """The victim hangs in the first scene task, or in the first pass of tile 2 (after the
    iteration's product is stored and tiles 0 and 1 are done); it is SIGKILLed there, a
    rescuer reclaims the task, and the image is still the local one bit for bit."""
    scene = tmp_path / f"sppmkill{target}.usda"
    shutil.copy(CAUSTIC, scene)
    reclaimed_before = int(redis_client.hget(rdb.STATS, "reclaimed") or 0)
    victim = start_worker(farm.redis_url, f"sppm-victim-{target}", farm.log_dir,
                          faults=f"hang:sppmkill*.usda#{target}")
    job = submit_job(farm, scene, FORM, PARAMS)
    queue = rdb.job_queue_key(job)
    deadline = time.monotonic() + 120

    def hanging_task():
        pending = redis_client.xpending_range(queue, rdb.WORKER_GROUP, "-", "+", 1,
                                              consumername=f"sppm-victim-{target}")
        if not pending:
            return None
        entry = redis_client.xrange(queue, pending[0]["message_id"], pending[0]["message_id"])
        if not entry:  # finished and acknowledged between the two reads
            return None
        return queue_tasks.TileTask.from_fields(entry[0][1])

    while True:
        task = hanging_task()
        wanted = task is not None and (task.scene_pass if target == "scene"
                                       else (not task.scene_pass and task.tile.index == 2))
        if wanted and child_pids(victim.pid):
            break
        assert time.monotonic() < deadline, "the victim never hung in its task\n" + victim.log()
        time.sleep(0.01)
    os.kill(victim.pid, signal.SIGKILL)
    victim.popen.wait(timeout=10)
    victim.stop()
    rescuer = start_worker(farm.redis_url, f"sppm-rescuer-{target}", farm.log_dir)
    try:
        status = wait_for_job(farm, job, timeout=180, processes=[rescuer], expect="done")
        assert int(redis_client.hget(rdb.STATS, "reclaimed") or 0) > reclaimed_before
        assert int(redis_client.hget(rdb.job_key(job), "scene_passes_stored")) == ITERATIONS
        assert_bit_identical(farm_image(farm, job, tmp_path), local_image(FORM, PARAMS, scene))
    finally:
        rescuer.stop()
