"""What the orchestrators read from a real farm (real redis-server, API and worker
processes): GET /scaling, the number KEDA scales the workers by
(deploy/k8s/worker-scaledobject.yaml), and `python -m tessera_worker.probe`, the worker
containers' health check."""
from __future__ import annotations

import subprocess
import sys

import httpx
import pytest

from conftest import CORNELL, clean_env, start_api, start_worker, submit, wait_for_job

pytestmark = pytest.mark.slow

TOKEN = "scaling-test-token"
# 3 x 2 tiles, one pass each (no noise target): six tile tasks, counted here from the
# settings, not from the code under test.
FORM = dict(width=48, height=32, tile_size=16, spp=1, seed=0, max_depth=2)
TILES = (48 // 16) * (32 // 16)


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("scaling"),
                           api_tokens=f"alice:{TOKEN}")
    with httpx.Client(base_url=base, timeout=60,
                      headers={"Authorization": f"Bearer {TOKEN}"}) as client:
        yield client
    proc.stop()


def open_tasks(api: httpx.Client) -> int:
    r = api.get("/scaling")
    assert r.status_code == 200, r.text
    return r.json()["open_tasks"]


def probe(redis_url: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tessera_worker.probe"], capture_output=True,
                          text=True, env=clean_env(REDIS_URL=redis_url), timeout=60)


def test_scaling_counts_the_open_tasks_of_runnable_jobs(api, redis_server, tmp_path):
    assert httpx.get(api.base_url.join("/scaling")).status_code == 401  # behind the API's auth
    assert api.get("/scaling").json() == {"open_tasks": 0, "workers": 0}
    r = submit(api, CORNELL, **FORM)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    assert open_tasks(api) == TILES
    assert api.post(f"/jobs/{job_id}/pause").status_code == 200
    assert open_tasks(api) == 0  # a paused job needs no worker
    assert api.post(f"/jobs/{job_id}/resume").status_code == 200
    assert open_tasks(api) == TILES
    worker = start_worker(redis_server, "sc-w", tmp_path)
    try:
        status = wait_for_job(api, job_id, processes=[worker], expect="done")
        assert api.get("/scaling").json() == {"open_tasks": 0, "workers": 1}
    finally:
        worker.stop()


def test_worker_probe_follows_the_heartbeat(redis_server, tmp_path):
    assert probe(redis_server).returncode == 1  # no worker on this host yet
    worker = start_worker(redis_server, "probe-w", tmp_path)
    try:
        alive = probe(redis_server)
        assert alive.returncode == 0, alive.stdout + alive.stderr
        assert "probe-w" in alive.stdout
    finally:
        worker.stop()
    # A clean exit removes the heartbeat at once.
    gone = probe(redis_server)
    assert gone.returncode == 1, gone.stdout
    # Redis down is not the worker's fault: healthy, so that it is not restarted for it.
    unreachable = probe("redis://127.0.0.1:1/0")
    assert unreachable.returncode == 0 and "cannot reach redis" in unreachable.stdout
