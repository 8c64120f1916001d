"""The API routes behind the monitor's task table, job filters and paging, on a real farm
(redis-server, the API with tokens for alice, bob and the admin root, one worker whose
render process fails on purpose: TESSERA_WORKER_FAULTS, docs/farm.md)."""
from __future__ import annotations

import shutil
import time
from datetime import datetime
from pathlib import Path

import httpx
import pytest

from conftest import CORNELL, start_api, start_worker, submit, wait_for_job
from tessera_queue import redis_schema as rdb

pytestmark = pytest.mark.slow

TOKENS = {"alice": "mon-alice-1", "bob": "mon-bob-1", "root": "mon-root-1"}
WORKER = "mon-worker"
# 64x64 in tiles of 32: four tiles, each one pass.
SMALL = dict(width=64, height=64, spp=2, max_depth=4, tile_size=32)


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("monitor-api")
    api, base = start_api(redis_server, logs, api_tokens=",".join(f"{u}:{t}" for u, t in TOKENS.items()),
                          api_admins="root")
    worker = start_worker(redis_server, WORKER, logs, tile_timeout=600.0,
                          faults="segv:poison*.usda#1,hang:stuck*.usda#15")
    clients = {u: httpx.Client(base_url=base, timeout=60, headers={"Authorization": f"Bearer {t}"})
               for u, t in TOKENS.items()}
    clients["processes"] = [api, worker]
    yield clients
    worker.stop()
    api.stop()


def named(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    shutil.copy(CORNELL, path)
    return path


def created(response: httpx.Response) -> str:
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_tasks_of_a_done_job(farm, tmp_path):
    alice = farm["alice"]
    job = created(submit(alice, CORNELL, **SMALL))
    status = wait_for_job(alice, job, processes=farm["processes"], expect="done")
    r = alice.get(f"/jobs/{job}/tasks")
    assert r.status_code == 200, r.text
    table = r.json()
    assert table["state"] == "done" and table["events_complete"] and table["scene_passes"] == []
    assert [(t["index"], t["x0"], t["y0"], t["width"], t["height"]) for t in table["tiles"]] == [
        (0, 0, 0, 32, 32), (1, 32, 0, 32, 32), (2, 0, 32, 32, 32), (3, 32, 32, 32, 32)]
    for tile in table["tiles"]:
        assert (tile["state"], tile["worker"], tile["passes_done"], tile["samples"], tile["attempts"]) == (
            "done", WORKER, 1, 2, 0), tile
        # When it was stored: the event's own time, inside the job's life. The event's time
        # is its stream id (Redis's clock, in ms) and the job's times the writers' clocks:
        # the same host here, but read at different moments of one store (a fresh-clone run
        # saw the last tile 3 ms after the job's finish), so 50 ms of slack.
        at = datetime.fromisoformat(tile["finished_at"])
        assert (datetime.fromisoformat(status["started_at"]).timestamp() - 0.05 <= at.timestamp()
                <= datetime.fromisoformat(status["finished_at"]).timestamp() + 0.05)
    # The tiles' seconds (each rounded to the millisecond) add up to the job's own sum,
    # kept separately in its hash.
    assert abs(sum(t["render_seconds"] for t in table["tiles"]) - status["render_seconds"]) <= 0.004
    # Owner-checked as every job route: another user's job is a 404, the admin sees it.
    assert farm["bob"].get(f"/jobs/{job}/tasks").status_code == 404
    assert farm["root"].get(f"/jobs/{job}/tasks").status_code == 200
    assert alice.get(f"/jobs/{'0' * 32}/tasks").status_code == 404
    assert alice.get("/jobs/not-an-id/tasks").status_code == 404


def test_a_failing_tile_shows_its_attempts_worker_and_error(farm, tmp_path):
    alice = farm["alice"]
    job = created(submit(alice, named(tmp_path, "poison.usda"), max_attempts=2, **SMALL))
    status = wait_for_job(alice, job, processes=farm["processes"], expect="failed")
    assert status["error"].startswith("tile 1 failed 2 times"), status
    table = alice.get(f"/jobs/{job}/tasks").json()
    tile = table["tiles"][1]
    assert (tile["state"], tile["attempts"], tile["worker"]) == ("failed", 2, WORKER), tile
    assert "SIGSEGV" in tile["last_error"]
    assert all(t["attempts"] == 0 and t["state"] in ("done", "abandoned")
               for t in table["tiles"] if t["index"] != 1), table


def test_list_filters_and_pages(farm, tmp_path):
    alice, bob, root = farm["alice"], farm["bob"], farm["root"]
    ids = {name: created(submit(client, named(tmp_path, f"{name}.usda"), **SMALL))
           for client, name in ((alice, "Alpha-one"), (alice, "beta-two"), (bob, "alpha-three"))}
    for name, job in ids.items():
        client = bob if name == "alpha-three" else alice
        wait_for_job(client, job, processes=farm["processes"], expect="done")

    def listed(client, **params) -> list[str]:
        r = client.get("/jobs", params=params)
        assert r.status_code == 200, r.text
        return [j["id"] for j in r.json()["jobs"]]

    # name: a case-insensitive part of the scene's name; each user sees only their own.
    assert listed(alice, name="ALPHA") == [ids["Alpha-one"]]
    assert listed(root, name="alpha") == [ids["alpha-three"], ids["Alpha-one"]]  # newest first
    assert listed(root, name="alpha", user="bob") == [ids["alpha-three"]]
    assert listed(alice, user="alice", name="beta") == [ids["beta-two"]]
    assert bob.get("/jobs", params={"user": "alice"}).status_code == 403
    assert ids["beta-two"] in listed(alice, state="done") and listed(alice, state="paused") == []
    # Pages: everything alice has, one by one, in the order of the whole list, and `more`
    # false on the last.
    everything = listed(alice, limit=1000)
    assert len(everything) >= 4  # the two above and the earlier tests' jobs
    pages, offset = [], 0
    while True:
        page = alice.get("/jobs", params={"limit": 1, "offset": offset}).json()
        pages += [j["id"] for j in page["jobs"]]
        assert page["offset"] == offset
        offset += 1
        if not page["more"]:
            break
    assert pages == everything


def test_a_hung_tile_is_shown_rendering_and_slow(farm, tmp_path):
    """Tile 15 of 16 hangs (fault injection): the other fifteen are timed, and the hung
    one is shown rendering on the worker and, once it has taken SLOW_FACTOR x their median
    and SLOW_MIN_EXCESS more, slow; the done ones (compared with their own median) are
    mostly not."""
    alice = farm["alice"]
    form = dict(SMALL, width=128, height=128)
    job = created(submit(alice, named(tmp_path, "stuck.usda"), **form))
    deadline = time.monotonic() + 120
    while True:
        table = alice.get(f"/jobs/{job}/tasks").json()
        hung = table["tiles"][15]
        if hung["state"] == "rendering" and hung["slow"]:
            break
        assert time.monotonic() < deadline, table
        time.sleep(0.1)
    median = table["median_pass_seconds"]
    assert hung["worker"] == WORKER and hung["rendering_seconds"] > max(table["slow_factor"] * median,
                                                                        median + table["slow_min_excess"])
    done = [t for t in table["tiles"] if t["index"] != 15]
    assert all(t["state"] == "done" for t in done), table
    assert sum(t["slow"] for t in done) < len(done) // 2, table
    r = alice.delete(f"/jobs/{job}")
    assert r.json()["state"] == "cancelled"
    assert all(t["state"] in ("done", "abandoned") for t in alice.get(f"/jobs/{job}/tasks").json()["tiles"])


def test_retry_and_purge(farm, tmp_path, redis_client):
    alice, bob = farm["alice"], farm["bob"]
    job = created(submit(alice, named(tmp_path, "poison.usda"), max_attempts=1, priority=7, **SMALL))
    wait_for_job(alice, job, processes=farm["processes"], expect="failed")
    assert bob.post(f"/jobs/{job}/retry").status_code == 404  # another user's: as if absent
    r = farm["root"].post(f"/jobs/{job}/retry")  # the admin retries it: it stays alice's
    assert r.status_code == 201, r.text
    again = r.json()["id"]
    assert again != job and r.headers["location"] == f"/jobs/{again}"
    old, new = alice.get(f"/jobs/{job}").json(), alice.get(f"/jobs/{again}").json()
    assert new["settings"] == old["settings"] and new["scene_name"] == "poison.usda"
    assert (new["owner"], new["priority"]) == ("alice", 7)
    assert alice.get(f"/jobs/{job}/log").json()["lines"][-1].endswith(f"retried as job {again}")
    assert alice.get(f"/jobs/{again}/log").json()["lines"][1].endswith(f"retry of job {job}")
    wait_for_job(alice, again, processes=farm["processes"], expect="failed")  # the same fault
    done = created(submit(alice, CORNELL, **SMALL))
    wait_for_job(alice, done, processes=farm["processes"], expect="done")
    r = alice.post(f"/jobs/{done}/retry")
    assert r.status_code == 409 and "only a failed or cancelled job" in r.text

    # Purge: a finished job goes at once, with every key it kept.
    assert any(redis_client.exists(k) for k in rdb.job_keys(job))
    assert bob.post(f"/jobs/{job}/purge").status_code == 404
    assert alice.post(f"/jobs/{job}/purge").status_code == 204
    assert alice.get(f"/jobs/{job}").status_code == 404
    assert not any(redis_client.exists(k) for k in rdb.job_keys(job))
    assert job not in [j["id"] for j in alice.get("/jobs", params={"limit": 1000}).json()["jobs"]]
    assert redis_client.zscore(rdb.JOB_INDEX, job) is None
    assert redis_client.zscore(rdb.user_jobs_key("alice"), job) is None


def test_retry_and_purge_a_frame_range(farm, tmp_path):
    alice = farm["alice"]
    farm["root"].post(f"/workers/{WORKER}/disable")  # the frames stay queued until cancelled
    try:
        r = submit(alice, CORNELL, frames="1-2", **SMALL)
        assert r.status_code == 201, r.text
        seq, frames = r.json()["id"], {f["frame"]: f["job"] for f in r.json()["frames"]}
        assert alice.post(f"/jobs/{seq}/purge").status_code == 409  # not finished
        assert alice.post(f"/jobs/{seq}/retry").status_code == 409  # nothing failed
        alice.delete(f"/jobs/{frames[2]}")  # frame 2 cancelled: the one to retry
        r = alice.post(f"/jobs/{seq}/retry")
        assert r.status_code == 201, r.text
        (retried,) = r.json()["frames"]
        assert retried["frame"] == 2 and retried["job"] != frames[2]
        status = alice.get(f"/jobs/{seq}").json()
        assert [(f["frame"], f["job"]) for f in status["frames"]] == [(1, frames[1]), (2, retried["job"])]
        assert alice.get(f"/jobs/{retried['job']}").json()["sequence"] == seq
        alice.delete(f"/jobs/{seq}")
        assert alice.post(f"/jobs/{seq}/purge").status_code == 204
        assert alice.get(f"/jobs/{seq}").status_code == 404
        assert all(alice.get(f"/jobs/{j}").status_code == 404 for j in (frames[1], retried["job"]))
        assert alice.get(f"/jobs/{frames[2]}").status_code == 200  # replaced, so not the range's: kept
    finally:
        farm["root"].post(f"/workers/{WORKER}/enable")


def test_worker_actions_are_for_admins(farm, redis_client):
    alice, root = farm["alice"], farm["root"]
    for method, path in (("POST", f"/workers/{WORKER}/disable"), ("POST", f"/workers/{WORKER}/enable"),
                         ("DELETE", f"/workers/{WORKER}/blocklist")):
        r = alice.request(method, path)
        assert r.status_code == 403 and "only an admin" in r.text, (path, r.text)
    assert root.post("/workers/no-such-worker/disable").status_code == 404
    assert not redis_client.exists(rdb.worker_key("no-such-worker"))  # not brought to life
    assert root.delete("/workers/no-such-worker/blocklist").json() == {"worker": "no-such-worker", "jobs": []}
    # Disabled, the worker takes nothing: a job waits (three heartbeats, longer than the
    # worker's idle wait) and is first picked after the enable.
    assert root.post(f"/workers/{WORKER}/disable").json()["disabled"] is True
    assert [w["disabled"] for w in alice.get("/workers").json()["workers"] if w["name"] == WORKER] == [True]
    job = created(submit(alice, CORNELL, **SMALL))
    beat = float(redis_client.hget(rdb.worker_key(WORKER), "beat_at"))
    deadline = time.monotonic() + 60
    beats = 0
    while beats < 3:
        now = float(redis_client.hget(rdb.worker_key(WORKER), "beat_at"))
        if now > beat:
            beats, beat = beats + 1, now
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert alice.get(f"/jobs/{job}").json()["state"] == "queued"
    enabled_at = time.time()
    assert root.post(f"/workers/{WORKER}/enable").json()["disabled"] is False
    status = wait_for_job(alice, job, processes=farm["processes"], expect="done")
    assert datetime.fromisoformat(status["started_at"]).timestamp() >= enabled_at


def test_scene_passes_are_rows_with_their_worker(farm):
    """An integrator with scene passes (photon_direct): one row per iteration's scene pass,
    done on the worker, as many as the tiles' passes (each iteration's tile passes follow
    its scene pass)."""
    alice = farm["alice"]
    # A noise target no image reaches: passes of 1, 1 and 2 samples up to max_spp 4, each
    # iteration its own scene pass (tests/renderer/test_scene_passes.py).
    form = dict(SMALL, spp=4, target_error=1e-6, min_spp=1, max_spp=4, integrator="photon_direct")
    job = created(submit(alice, CORNELL, **form))
    wait_for_job(alice, job, processes=farm["processes"], expect="done")
    table = alice.get(f"/jobs/{job}/tasks").json()
    iterations = max(t["pass_index"] for t in table["tiles"]) + 1
    assert iterations == 3, table
    assert [(s["index"], s["state"], s["worker"]) for s in table["scene_passes"]] == [
        (i, "done", WORKER) for i in range(iterations)], table
    assert all(t["passes_done"] == iterations for t in table["tiles"]), table
