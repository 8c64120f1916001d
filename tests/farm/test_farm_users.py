"""Jobs per user, through a real uvicorn API, redis-server and worker: a token names a
user, a job belongs to whoever submitted it, another user's job is a 404 exactly like a
job that does not exist, and an admin sees and controls everyone's."""
from __future__ import annotations

import subprocess
import sys
import time

import httpx
import pytest

from conftest import CORNELL, STARTUP_TIMEOUT, clean_env, start_api, start_worker, submit, wait_for_job
from tessera_cli.embedded import free_port

TOKENS = {"alice": "tok-alice-1", "bob": "tok-bob-1", "root": "tok-root-1"}
# Render settings of a job that finishes in well under a second.
QUICK = dict(width=32, height=32, spp=1, tile_size=32)


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("users")
    # alice has a second token: both are the same user.
    tokens = ",".join(f"{user}:{token}" for user, token in TOKENS.items()) + ",alice:tok-alice-2"
    api, base = start_api(redis_server, log_dir, api_tokens=tokens, api_admins="root")
    clients = {user: httpx.Client(base_url=base, timeout=60,
                                  headers={"Authorization": f"Bearer {token}"})
               for user, token in TOKENS.items()}
    clients["alice-2"] = httpx.Client(base_url=base, timeout=60,
                                      headers={"Authorization": "Bearer tok-alice-2"})
    yield clients, redis_server, log_dir
    for client in clients.values():
        client.close()
    api.stop()


def _queued(client: httpx.Client) -> str:
    """A job that stays queued (no worker runs while it exists)."""
    r = submit(client, CORNELL, **QUICK)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _listed(client: httpx.Client) -> set[str]:
    r = client.get("/jobs", params={"limit": 1000})
    assert r.status_code == 200, r.text
    return {job["id"] for job in r.json()["jobs"]}


def test_users_list_and_see_only_their_own_jobs(farm):
    clients, _, _ = farm
    alice, bob, root = clients["alice"], clients["bob"], clients["root"]
    a, b = _queued(alice), _queued(bob)
    try:
        assert a in _listed(alice) and b not in _listed(alice)
        assert b in _listed(bob) and a not in _listed(bob)
        assert {a, b} <= _listed(root)  # the admin sees all
        assert a in _listed(clients["alice-2"])  # the same user under another token
        assert alice.get(f"/jobs/{a}").json()["owner"] == "alice"
        assert root.get(f"/jobs/{b}").json()["owner"] == "bob"

        # Another user's id answers exactly as an id that names no job: nothing leaks.
        nobody = "0" * 32
        for method, path in (("GET", ""), ("GET", "/log"), ("GET", "/events"),
                             ("GET", "/preview.png"), ("GET", "/denoised.png"), ("GET", "/image.exr"),
                             ("DELETE", ""), ("POST", "/pause"), ("POST", "/resume")):
            theirs = bob.request(method, f"/jobs/{a}{path}")
            unknown = bob.request(method, f"/jobs/{nobody}{path}")
            assert theirs.status_code == unknown.status_code == 404, (method, path, theirs.text)
            assert theirs.json()["detail"].replace(a, nobody) == unknown.json()["detail"]
        # ... and none of bob's attempts changed alice's job.
        assert alice.get(f"/jobs/{a}").json()["state"] == "queued"

        # The admin controls bob's job; alice cancels her own.
        assert root.post(f"/jobs/{b}/pause").json()["state"] == "paused"
        assert bob.get(f"/jobs/{b}").json()["state"] == "paused"
        assert root.post(f"/jobs/{b}/resume").json()["state"] == "queued"
        assert alice.delete(f"/jobs/{a}").json()["state"] == "cancelled"
    finally:
        root.delete(f"/jobs/{a}")
        root.delete(f"/jobs/{b}")


def test_only_the_owner_downloads_and_streams_a_finished_job(farm, tmp_path):
    clients, redis_url, log_dir = farm
    alice, bob, root = clients["alice"], clients["bob"], clients["root"]
    job = _queued(alice)
    worker = start_worker(redis_url, "users-w1", log_dir)
    try:
        assert wait_for_job(alice, job, processes=[worker])["state"] == "done"
    finally:
        worker.stop()
    for path in ("/image.exr", "/preview.png", "/events"):
        assert bob.get(f"/jobs/{job}{path}").status_code == 404, path
        r = alice.get(f"/jobs/{job}{path}")
        assert r.status_code == 200, (path, r.text)
        assert r.content == root.get(f"/jobs/{job}{path}").content, path
    assert alice.get(f"/jobs/{job}/image.exr").content[:4] == b"\x76\x2f\x31\x01"  # EXR magic


@pytest.mark.parametrize("tokens, admins, message", [
    ("alice:same-token,bob:same-token", "", "entry 2: user bob has the same token as user alice"),
    ("alice:tok-1,bad name:tok-2", "", "entry 2: 'bad name' is not a valid user name"),
    ("alice:tok-1", "carol", "TESSERA_API_ADMINS names users without a token: carol"),
])
def test_an_unusable_token_configuration_stops_the_api_at_start(tokens, admins, message):
    proc = subprocess.run([sys.executable, "-m", "uvicorn", "--factory",
                           "tessera_service.app:create_app", "--port", str(free_port())],
                          env=clean_env(TESSERA_API_TOKENS=tokens, TESSERA_API_ADMINS=admins,
                                        TESSERA_REDIS_URL="redis://127.0.0.1:1/0"),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert message in proc.stderr, proc.stderr[-2000:]


def test_workers_show_only_your_own_job_as_current(farm):
    """/workers names the job a worker renders to its owner and to admins; to anyone else
    it says only that it is another user's job (the id would leak otherwise)."""
    clients, redis_url, log_dir = farm
    alice, bob, root = clients["alice"], clients["bob"], clients["root"]
    r = submit(alice, CORNELL, width=64, height=64, spp=4096, tile_size=8)  # minutes of work
    assert r.status_code == 201, r.text
    job = r.json()["id"]
    worker = start_worker(redis_url, "users-w2", log_dir)
    def until(what, client, condition):
        # Between two tiles a heartbeat may say "idle": poll until the worker is seen busy.
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while True:
            workers = client.get("/workers").json()["workers"]
            assert job not in str(workers) or client is not bob, workers  # never leaked
            if workers and condition(workers[0]["current"] or ""):
                return
            assert worker.alive() and time.monotonic() < deadline, what + worker.log()
            time.sleep(0.02)

    try:
        until("the admin sees the job", root, lambda current: current.startswith(job))
        until("its owner sees it", alice, lambda current: current.startswith(job))
        until("bob sees someone's", bob, lambda current: current == "another user's job")
    finally:
        root.delete(f"/jobs/{job}")
        worker.stop()
