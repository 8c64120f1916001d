"""A farm on several "hosts": Linux network namespaces joined by veth pairs, on this
machine only. Redis and the API run in namespace "hub"; workers run in "w1" (two) and
"w2" (one) and reach the hub only over their veth link; this test (the client) reaches the
API over a third link. w1's workers are killed mid-job; w2 finishes the job, and the image
equals the local render. Needs root and iproute2 (scripts/setup.sh installs it)."""
from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import time

import httpx
import numpy as np
import pytest
import redis

from conftest import CORNELL, Process, clean_env, start_api, start_worker, submit, wait_for_job
from tessera_base import images, protocol
from tessera_queue import redis_schema as rdb
from tessera.local import render_image
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene

TOKEN = "netns-test-token"


def ip(*args: str, ns: str | None = None) -> None:
    cmd = (["ip", "netns", "exec", ns, "ip"] if ns else ["ip"]) + list(args)
    subprocess.run(cmd, check=True, capture_output=True, text=True)


@pytest.fixture
def hosts():
    """Three namespaces and the links between them; removed afterwards."""
    assert os.geteuid() == 0 and shutil.which("ip"), "needs root and iproute2"
    tag = f"{os.getpid() % 1000:03d}{random.randrange(100):02d}"
    net = random.randrange(16, 250)
    names = {role: f"ts{tag}{role}" for role in ("hub", "w1", "w2")}
    addrs = {}
    try:
        for ns in names.values():
            ip("netns", "add", ns)
            ip("link", "set", "lo", "up", ns=ns)
        # (link name in root ns, peer ns, address here, address there); here = root or hub.
        links = [("c", None, names["hub"], f"10.{net}.0.1", f"10.{net}.0.2"),
                 ("1", names["hub"], names["w1"], f"10.{net}.1.1", f"10.{net}.1.2"),
                 ("2", names["hub"], names["w2"], f"10.{net}.2.1", f"10.{net}.2.2")]
        for suffix, here, there, a, b in links:
            left, right = f"ts{tag}{suffix}a", f"ts{tag}{suffix}b"
            ip("link", "add", left, "type", "veth", "peer", "name", right)
            if here:
                ip("link", "set", left, "netns", here)
            ip("link", "set", right, "netns", there)
            ip("addr", "add", f"{a}/30", "dev", left, ns=here)
            ip("link", "set", left, "up", ns=here)
            ip("addr", "add", f"{b}/30", "dev", right, ns=there)
            ip("link", "set", right, "up", ns=there)
        addrs = {"client->hub": f"10.{net}.0.2", "w1->hub": f"10.{net}.1.1",
                 "w2->hub": f"10.{net}.2.1", "w1": f"10.{net}.1.2", "w2": f"10.{net}.2.2"}
        yield names, addrs
    finally:
        for ns in names.values():
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        # Deleting a namespace deletes the veth ends in it, and so their peers.
        subprocess.run(["ip", "link", "del", f"ts{tag}ca"], capture_output=True)


def test_workers_on_other_hosts_one_host_dies(hosts, tmp_path):
    names, addrs = hosts
    in_ns = {role: ["ip", "netns", "exec", ns] for role, ns in names.items()}
    port = 6379
    redis_proc = Process("redis-hub", [*in_ns["hub"], shutil.which("redis-server"), "--port",
                                       str(port), "--bind", "0.0.0.0", "--protected-mode", "no",
                                       "--save", "", "--appendonly", "no", "--dir", str(tmp_path)],
                         tmp_path, clean_env())
    processes = [redis_proc]
    try:
        hub_redis = redis.Redis(host=addrs["client->hub"], port=port, socket_connect_timeout=1)
        deadline = time.monotonic() + 30
        while True:
            try:
                hub_redis.ping()
                break
            except redis.ConnectionError:
                assert redis_proc.alive(), redis_proc.log()
                assert time.monotonic() < deadline, redis_proc.log()
                time.sleep(0.05)
        # The API listens on every address of the hub, so it requires a token.
        watch = f"redis://{addrs['client->hub']}:{port}/0"
        api, base = start_api(f"redis://127.0.0.1:{port}/0", tmp_path, host="0.0.0.0",
                              cmd_prefix=in_ns["hub"], public_host=addrs["client->hub"],
                              api_tokens=TOKEN)
        processes.append(api)
        w1 = [start_worker(f"redis://{addrs['w1->hub']}:{port}/0", f"w1-{i}", tmp_path,
                           cmd_prefix=in_ns["w1"], watch_url=watch) for i in range(2)]
        w2 = start_worker(f"redis://{addrs['w2->hub']}:{port}/0", "w2-0", tmp_path,
                          cmd_prefix=in_ns["w2"], watch_url=watch)
        processes += [*w1, w2]
        # Each worker really talks to Redis from its own host's address.
        client_addrs = {c["addr"].rsplit(":", 1)[0] for c in hub_redis.client_list()}
        assert {addrs["w1"], addrs["w2"]} <= client_addrs, client_addrs

        headers = {"Authorization": f"Bearer {TOKEN}"}
        with httpx.Client(base_url=base, timeout=60, headers=headers) as client:
            assert httpx.get(f"{base}/jobs").status_code == 401
            form = dict(width=64, height=64, spp=256, seed=13, max_depth=16, tile_size=16)
            r = submit(client, CORNELL, **form)
            assert r.status_code == 201, r.text
            job_id = r.json()["id"]
            queue = rdb.job_queue_key(job_id)
            deadline = time.monotonic() + 120
            while True:  # kill host w1 while it holds tiles of the job
                held = sum(len(hub_redis.xpending_range(queue, rdb.WORKER_GROUP, "-", "+",
                                                        10, consumername=w.name)) for w in w1)
                status = client.get(f"/jobs/{job_id}").json()
                if held and status["tiles_done"] > 0:
                    break
                assert status["state"] not in protocol.FINAL_STATES, status
                assert time.monotonic() < deadline, "w1 never held a tile"
                time.sleep(0.01)
            for w in w1:
                os.kill(w.pid, signal.SIGKILL)
            status = wait_for_job(client, job_id, timeout=180, processes=processes, expect="done")
            rendered_by_w2 = int(hub_redis.hget(rdb.worker_key("w2-0"), "tiles_done") or 0)
            assert rendered_by_w2 > 0
            r = client.get(f"/jobs/{job_id}/image.exr")
            assert r.status_code == 200
            (tmp_path / "farm.exr").write_bytes(r.content)
        expected = render_image(load_scene(str(CORNELL)), RenderSettings(**form), threads=0,
                                progress=False).rgba
        actual = images.read_exr(tmp_path / "farm.exr")
        assert np.array_equal(actual.view(np.uint32), expected.view(np.uint32))
        hub_redis.close()
    finally:
        for p in reversed(processes):
            p.stop()


def test_api_without_tokens_answers_only_on_loopback(hosts, redis_server, tmp_path):
    """However it is launched (here a bare `uvicorn --host 0.0.0.0`, not `tessera serve`,
    which would refuse), an API without tokens refuses requests that arrive on a
    non-loopback address (this namespace's end of the veth link) and answers on loopback."""
    names, addrs = hosts
    here = addrs["client->hub"].rsplit(".", 1)[0] + ".1"  # the root namespace's end
    api, base = start_api(redis_server, tmp_path, host="0.0.0.0", public_host="127.0.0.1")
    try:
        port = base.rsplit(":", 1)[1]
        assert httpx.get(f"{base}/jobs", timeout=10).status_code == 200
        r = httpx.get(f"http://{here}:{port}/jobs", timeout=10)
        assert r.status_code == 403, r.text
        assert "TESSERA_API_TOKENS" in r.json()["detail"] and here in r.json()["detail"]
        assert httpx.get(f"http://{here}:{port}/healthz", timeout=10).status_code == 200
    finally:
        api.stop()
