"""The farm's Redis users (tessera_service.redis_acl) on a real redis-server: connections
without a password are refused, the worker user cannot run what it should not (FLUSHALL,
CONFIG, KEYS, ...) nor read or write pre-flight results and the job indexes, the API and a worker do a real
job's whole life under their users, and deploy/users.acl says the same as the code."""
from __future__ import annotations

import re
import subprocess
import sys
import time

import httpx
import pytest
import redis
from redis.backoff import NoBackoff
from redis.retry import Retry

from conftest import (CORNELL, REPO, STARTUP_TIMEOUT, clean_env, start_api, start_worker, submit,
                      wait_for_job)
from tessera_queue import redis_schema as rdb
from tessera_cli.embedded import free_port, redis_server, stop_processes
from tessera_service.redis_acl import (API_USER, DEFAULT_RULE, WORKER_USER, Credentials,
                                      aof_replay_problem, user_rule)

SCENE = rdb.scene_key("0" * 64)
PREFLIGHT = rdb.preflight_key("0" * 64, ".usda")


@pytest.fixture(scope="module")
def acl_redis(tmp_path_factory):
    with redis_server(str(tmp_path_factory.mktemp("acl")), credentials=Credentials.generate()) as local:
        yield local


@pytest.fixture
def worker_client(acl_redis):
    client = redis.Redis.from_url(acl_redis.worker_url)
    yield client
    client.close()


@pytest.fixture
def api_client(acl_redis):
    client = redis.Redis.from_url(acl_redis.url)
    yield client
    client.close()


def test_connections_without_the_password_are_refused(acl_redis):
    once = dict(port=acl_redis.port, protocol=2, retry=Retry(NoBackoff(), 0))
    with redis.Redis(**once) as anonymous:
        with pytest.raises(redis.AuthenticationError, match="Authentication required"):
            anonymous.ping()
    with redis.Redis(username=WORKER_USER, password="guess", **once) as wrong:
        with pytest.raises(redis.AuthenticationError, match="invalid username-password"):
            wrong.ping()


@pytest.mark.parametrize("command", [
    ("FLUSHALL",), ("FLUSHDB",), ("CONFIG", "GET", "*"), ("CONFIG", "SET", "dir", "/tmp"),
    ("KEYS", "*"), ("SCAN", "0"), ("SORT", "tessera:active"), ("RANDOMKEY",), ("SHUTDOWN", "NOSAVE"), ("ACL", "LIST"),
    ("MONITOR",), ("INFO",), ("CLIENT", "LIST"), ("REPLICAOF", "NO", "ONE"), ("SCRIPT", "FLUSH"),
    ("FUNCTION", "LOAD", "#!lua name=x\nredis.register_function('f', function() return 1 end)"),
    ("MODULE", "LIST"), ("SAVE",), ("BGREWRITEAOF",),
])
@pytest.mark.parametrize("user", [WORKER_USER, API_USER])
def test_neither_user_may_run_admin_or_dangerous_commands(acl_redis, worker_client, api_client,
                                                          user, command):
    client = worker_client if user == WORKER_USER else api_client
    with pytest.raises(redis.exceptions.NoPermissionError):
        client.execute_command(*command)
    assert client.ping()  # still connected and usable: the server was not touched


def test_the_worker_reaches_scenes_and_jobs_but_not_preflights_or_indexes(worker_client, api_client):
    api_client.hset(SCENE, mapping={"name": "s.usda", "size": 9})
    api_client.set(PREFLIGHT, "{}")
    # What a worker does (the controls: these must work).
    assert worker_client.hget(SCENE, "name") == b"s.usda"
    worker_client.hset(rdb.job_tiles_key("1" * 32), "0:0", b"tile")
    worker_client.hincrby(rdb.STATS, "tiles", 1)
    worker_client.hset(SCENE, rdb.translated_field("v1"), "2" * 64)
    # ... and the data store's index of the translated scene it stores (data_store.hold).
    worker_client.hset(rdb.data_key("2" * 64), "size", 4)
    worker_client.sadd(rdb.data_holders_key("2" * 64), SCENE)
    worker_client.sadd(rdb.DATA_OBJECTS, "2" * 64)
    worker_client.set(rdb.DATA_STORE_ID, "x", nx=True)
    worker_client.srem(rdb.scene_jobs_key("0" * 64), "1" * 32)
    # What it must not.
    for denied in (lambda c: c.get(PREFLIGHT),
                   lambda c: c.set(PREFLIGHT, '{"width": 1}'),
                   lambda c: c.zadd(rdb.JOB_INDEX, {"x": 1}),
                   lambda c: c.zrange(rdb.user_jobs_key("alice"), 0, -1),
                   lambda c: c.get(rdb.blob_key("0" * 64)),
                   lambda c: c.set("elsewhere", 1),
                   # ... also from inside a script: ACLs apply to the commands a script runs.
                   lambda c: c.eval(f"return redis.call('SET', '{PREFLIGHT}', 'x')", 0)):
        with pytest.raises(redis.ResponseError, match="(?i)no permissions|can't access"):
            denied(worker_client)
    assert api_client.hget(SCENE, "size") == b"9"
    assert api_client.get(PREFLIGHT) == b"{}"


@pytest.mark.slow
def test_a_farm_runs_every_job_kind_under_its_redis_users(acl_redis, tmp_path):
    """API and worker processes on the ACL'd Redis: fixed-spp, noise-target bdpt (lockstep
    passes), pause/resume, cancel, an image download (cached), events and /workers, with
    no command refused (a refusal fails the job or shows as NOPERM in the logs)."""
    api, base = start_api(acl_redis.url, tmp_path)
    worker = start_worker(acl_redis.worker_url, "acl-w1", tmp_path)
    try:
        with httpx.Client(base_url=base, timeout=60) as client:
            ids = []
            for form in (dict(width=16, height=16, spp=2, tile_size=8),
                         dict(width=16, height=16, tile_size=8, integrator="bdpt",
                              target_error=0.5, min_spp=2, max_spp=4)):
                r = submit(client, CORNELL, **form)
                assert r.status_code == 201, r.text
                ids.append(r.json()["id"])
            paused = submit(client, CORNELL, width=16, height=16, spp=1, tile_size=8).json()["id"]
            assert client.post(f"/jobs/{paused}/pause").status_code == 200
            # The task table reads the queue's consumer group (XPENDING) while it exists.
            assert client.get(f"/jobs/{paused}/tasks").status_code == 200
            assert client.post(f"/jobs/{paused}/resume").status_code == 200
            ids.append(paused)
            cancelled = submit(client, CORNELL, width=64, height=64, spp=64, tile_size=8).json()["id"]
            assert client.delete(f"/jobs/{cancelled}").json()["state"] == "cancelled"
            for job in ids:
                status = wait_for_job(client, job, processes=[api, worker], expect="done")
                for _ in range(2):  # the second download is the cached image
                    r = client.get(f"/jobs/{job}/image.exr")
                    assert r.status_code == 200, r.text
                assert client.get(f"/jobs/{job}/events").status_code == 200
            assert client.get("/workers").json()["workers"][0]["name"] == "acl-w1"
            # The monitor's actions: worker disable/enable (EVAL), blocklists, retry, purge.
            assert client.post("/workers/acl-w1/disable").json()["disabled"] is True
            assert client.post("/workers/acl-w1/enable").json()["disabled"] is False
            assert client.delete("/workers/acl-w1/blocklist").status_code == 200
            retried = client.post(f"/jobs/{cancelled}/retry")
            assert retried.status_code == 201, retried.text
            assert client.delete(f"/jobs/{retried.json()['id']}").status_code == 200
            assert client.post(f"/jobs/{cancelled}/purge").status_code == 204
            assert client.get("/metrics").status_code == 200
            assert client.get("/healthz").json()["status"] == "ok"
    finally:
        worker.stop()
        api.stop()
    for proc in (api, worker):
        assert "NOPERM" not in proc.log_path.read_text(errors="replace"), proc.log(80)


def test_deploy_users_acl_grants_what_the_code_grants():
    """deploy/users.acl is the same rules with placeholder passwords (an ACL file has no
    comments: deploy/redis.conf and deploy/README.md explain it)."""
    rules = (REPO / "deploy" / "users.acl").read_text().splitlines()
    assert rules[0] == DEFAULT_RULE == "user default off ~* &* +@all"
    for name in (API_USER, WORKER_USER):
        [line] = [r for r in rules if r.startswith(f"user {name} ")]
        password = re.search(r" >(\S+)", line).group(1)
        assert password.startswith("CHANGE-ME"), line
        assert line == user_rule(name, password)
    assert len(rules) == 3


def test_deploy_redis_conf_starts_and_enforces_the_users(tmp_path):
    """deploy/redis.conf with deploy/users.acl (paths and port moved into tmp_path) runs on
    this redis-server, refuses anonymous clients and the worker's FLUSHALL."""
    port = free_port()
    conf = (REPO / "deploy" / "redis.conf").read_text()
    conf = conf.replace("/etc/redis/tessera-users.acl", str(REPO / "deploy" / "users.acl")) \
               .replace("/var/lib/tessera/redis", str(tmp_path)).replace("port 6379", f"port {port}")
    assert f"port {port}" in conf and str(tmp_path) in conf
    (tmp_path / "redis.conf").write_text(conf)
    proc = subprocess.Popen(["redis-server", str(tmp_path / "redis.conf"), "--daemonize", "no"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    once = dict(port=port, protocol=2)
    try:
        worker = redis.Redis(username=WORKER_USER, password="CHANGE-ME-worker-password", **once)
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while True:  # until it accepts connections
            assert proc.poll() is None, "redis-server rejected deploy/redis.conf"
            try:
                worker.ping()
                break
            except redis.ConnectionError:
                assert time.monotonic() < deadline
                time.sleep(0.05)
        with pytest.raises(redis.exceptions.NoPermissionError):
            worker.flushall()
        with redis.Redis(retry=Retry(NoBackoff(), 0), **once) as anonymous:
            with pytest.raises(redis.AuthenticationError):
                anonymous.ping()
        worker.close()
    finally:
        stop_processes([proc], 10.0)


# Redis 7.0 replays its append-only file as the default user and re-checks ACLs at EXEC;
# the default user of the shipped ACL must let it (redis_acl's docstring).
RESTART_KEYS = {"tessera:job:t1": {"state": "queued"}, "tessera:job:t2": {"state": "done"}}


def _write_and_restart(workdir, credentials, how: str) -> redis.Redis:
    """Writes as the API user what the farm writes (a MULTI/EXEC transaction, a Lua
    script's effects and a plain command) into an fsynced AOF, restarts Redis (`how`:
    SIGKILL or a graceful SIGTERM) in the same directory with the same ACL, and returns a
    client of the new server."""
    port = free_port()
    with redis_server(str(workdir), port=port, appendonly=True, credentials=credentials) as first:
        with redis.Redis.from_url(first.url) as api:
            with api.pipeline(transaction=True) as tx:
                tx.hset("tessera:job:t1", "state", "queued")
                tx.rpush("tessera:ready", "t1")
                tx.execute()
            api.eval("redis.call('HSET', KEYS[1], 'state', 'done') "
                     "return redis.call('SADD', KEYS[2], 't2')", 2, "tessera:job:t2", "tessera:active")
            api.set("tessera:plain", "1")
        if how == "SIGKILL":
            first.process.kill()
            first.process.wait()
    return redis_server(str(workdir), port=port, appendonly=True, credentials=credentials)


@pytest.mark.parametrize("how", ["SIGKILL", "graceful"])
def test_transactions_survive_a_restart_under_the_shipped_acl(tmp_path, how):
    """With `user default off -@all` (the ACL shipped before) both drills lost the
    transaction and the script's effects (Redis logged -NOPERM at load, the plain SET
    survived); with the shipped default rule every write is back."""
    credentials = Credentials.generate()
    with _write_and_restart(tmp_path, credentials, how) as second:
        with redis.Redis.from_url(second.url) as api:
            assert api.get("tessera:plain") == b"1"  # the control: replay happened at all
            assert api.hget("tessera:job:t1", "state") == b"queued", "a transaction was dropped"
            assert api.lrange("tessera:ready", 0, -1) == [b"t1"]
            assert api.hget("tessera:job:t2", "state") == b"done", "a script's effects were dropped"
            assert api.smembers("tessera:active") == {b"t2"}
    assert "NOPERM" not in (tmp_path / "redis.log").read_text()


@pytest.mark.slow  # two uvicorn processes: 6 s
@pytest.mark.parametrize("dryrun", [True, False])
def test_the_api_refuses_a_redis_that_would_drop_its_aof(tmp_path, dryrun):
    """The API's start-up check (ACL DRYRUN as the API user): the old default rule makes
    the API exit with a message that names the fix; with the shipped rule (the control)
    the check passes; a user without ACL DRYRUN cannot tell, and the API starts with a
    warning saying so."""
    api_rule = user_rule(API_USER, "pw")
    if not dryrun:
        api_rule = api_rule.replace(" +acl|dryrun", "")
    with redis_server(str(tmp_path)) as local:
        with redis.Redis.from_url(local.url) as admin:
            admin.execute_command("ACL", "SETUSER", *api_rule.split()[1:])
            api_url = f"redis://{API_USER}:pw@127.0.0.1:{local.port}/0"
            with redis.Redis.from_url(api_url) as api:
                assert aof_replay_problem(api) is None  # default: nopass +@all ~* &*
                admin.execute_command("ACL", "SETUSER", "default", "off", "resetkeys",
                                      "resetchannels", "-@all")
                problem = aof_replay_problem(api)
        if dryrun:
            assert problem is not None and "MULTI, EXEC, HSET" in problem and DEFAULT_RULE in problem
        else:
            assert problem is None
        port = free_port()
        cmd = [sys.executable, "-m", "uvicorn", "--factory", "tessera_service.app:create_app",
               "--port", str(port), "--log-level", "warning"]
        env = clean_env(TESSERA_REDIS_URL=api_url, TESSERA_ALLOW_ANONYMOUS_LOOPBACK="1")
        if dryrun:
            run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
            assert run.returncode != 0
            assert "refusing to start: Redis 7." in run.stderr and DEFAULT_RULE in run.stderr, run.stderr
        else:
            log = tmp_path / "api.log"
            with open(log, "wb") as out:
                proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT)
            try:
                deadline = time.monotonic() + STARTUP_TIMEOUT
                while True:  # it starts: /healthz answers
                    assert proc.poll() is None, log.read_text()
                    try:
                        if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                            break
                    except httpx.TransportError:
                        pass
                    assert time.monotonic() < deadline, log.read_text()
                    time.sleep(0.05)
            finally:
                stop_processes([proc], 10.0)
            assert "may not run ACL DRYRUN" in log.read_text()


@pytest.fixture(scope="module")
def acl_api(acl_redis, tmp_path_factory):
    """An API process with tokens on the shipped-ACL Redis, as its API user (no workers)."""
    api, base = start_api(acl_redis.url, tmp_path_factory.mktemp("acl-api"), api_tokens="alice:a-token")
    with httpx.Client(base_url=base, timeout=60, headers={"Authorization": "Bearer a-token"}) as client:
        client.api = api
        yield client
    api.stop()


def test_healthz_answers_while_jobs_are_queued_under_the_shipped_acl(acl_api, api_client):
    """/healthz (the k8s readiness probe) with a job queued: it answered 500 (the API user
    may not run TIME). The stall age it reports is the age of the newest event, checked
    against an event stream rewritten to 1 s after the epoch (the negative control: a
    fresh job shows no stall)."""
    job = submit(acl_api, CORNELL, width=16, height=16, spp=1, tile_size=8).json()["id"]
    try:
        for _ in range(20):
            r = acl_api.get("/healthz")
            assert r.status_code == 200, r.text
            assert not any("progressed" in p for p in r.json()["problems"]), r.json()
        events = rdb.job_events_key(job)
        api_client.delete(events)
        api_client.xadd(events, {"type": "state"}, id="1000-0")
        before = time.time()
        r = acl_api.get("/healthz")
        after = time.time()
        assert r.status_code == 200, r.text
        [stall] = [p for p in r.json()["problems"] if "progressed" in p]
        seconds = float(re.search(r"for (\d+) s", stall).group(1))
        assert before - 1 - 1 <= seconds <= after - 1 + 1, (stall, before, after)
    finally:
        acl_api.delete(f"/jobs/{job}")
    assert "NOPERM" not in acl_api.api.log_path.read_text(errors="replace")
    assert "NoPermissionError" not in acl_api.api.log_path.read_text(errors="replace")
