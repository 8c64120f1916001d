"""POST /jobs/{id}/priority (set_priority.lua) against a real redis-server and API, no
workers: the ready set, which the workers' pick.lua reads in order, shows the change."""
from __future__ import annotations

import httpx
import pytest

from conftest import CORNELL, start_api, submit
from tessera_queue import redis_schema as rdb

BAND = rdb.BAND


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("api"))
    with httpx.Client(base_url=base, timeout=60) as client:
        yield client
    proc.stop()


def ready_order(redis_client) -> list[str]:
    return [i.decode() for i in redis_client.zrange(rdb.READY, 0, -1)]


def band(redis_client, job: str) -> int:
    """The priority the ready set schedules the job at (redis_schema: the score's band)."""
    return 9 - int(redis_client.zscore(rdb.READY, job) // BAND)


def test_raised_priority_goes_first(api, redis_client):
    low = submit(api, CORNELL, spp=1, tile_size=256, priority=2).json()["id"]
    high = submit(api, CORNELL, spp=1, tile_size=256, priority=5).json()["id"]
    try:
        # Negative control: as submitted, the priority-5 job is served first.
        order = ready_order(redis_client)
        assert order.index(high) < order.index(low)
        r = api.post(f"/jobs/{low}/priority", json={"priority": 9})
        assert r.status_code == 200, r.text
        assert r.json()["priority"] == 9 and r.json()["state"] == "queued"
        assert api.get(f"/jobs/{low}").json()["priority"] == 9
        assert [j["priority"] for j in api.get("/jobs").json()["jobs"] if j["id"] == low] == [9]
        order = ready_order(redis_client)
        assert order.index(low) < order.index(high)
        assert band(redis_client, low) == 9 and band(redis_client, high) == 5
        assert any(line.endswith("priority changed from 2 to 9")
                   for line in api.get(f"/jobs/{low}/log").json()["lines"])
    finally:
        api.delete(f"/jobs/{low}")
        api.delete(f"/jobs/{high}")


def test_paused_job_comes_back_at_its_new_priority(api, redis_client):
    job = submit(api, CORNELL, spp=1, tile_size=256, priority=5).json()["id"]
    try:
        assert api.post(f"/jobs/{job}/pause").json()["state"] == "paused"
        r = api.post(f"/jobs/{job}/priority", json={"priority": 7})
        assert r.status_code == 200 and r.json()["state"] == "paused"
        assert redis_client.zscore(rdb.READY, job) is None  # still out of the ready set
        assert api.post(f"/jobs/{job}/resume").json()["state"] == "queued"
        assert band(redis_client, job) == 7
    finally:
        api.delete(f"/jobs/{job}")


def test_final_job_keeps_its_priority(api):
    job = submit(api, CORNELL, spp=1, tile_size=256, priority=3).json()["id"]
    assert api.delete(f"/jobs/{job}").json()["state"] == "cancelled"
    r = api.post(f"/jobs/{job}/priority", json={"priority": 8})
    assert r.status_code == 200 and r.json()["priority"] == 3
    assert not any("priority changed" in line for line in api.get(f"/jobs/{job}/log").json()["lines"])


@pytest.mark.parametrize("body", [{"priority": 10}, {"priority": -1}, {"priority": "high"},
                                  {"priority": 2.5}, {}])
def test_bad_priority_is_422_naming_the_field(api, body):
    job = submit(api, CORNELL, spp=1, tile_size=256).json()["id"]
    try:
        r = api.post(f"/jobs/{job}/priority", json=body)
        assert r.status_code == 422, r.text
        assert any(e["loc"][-1] == "priority" for e in r.json()["detail"]), r.text
        assert api.get(f"/jobs/{job}").json()["priority"] == 5
    finally:
        api.delete(f"/jobs/{job}")


def test_unknown_job_is_404(api):
    for job in ("nope", "0" * 32):
        r = api.post(f"/jobs/{job}/priority", json={"priority": 1})
        assert r.status_code == 404 and "no job with id" in r.json()["detail"]
