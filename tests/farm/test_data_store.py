"""The farm's large bytes live in the shared data directory, not in the queue's Redis
(issue 42, items 7 and 13: six 250 MiB PUT /blobs filled the deploy Redis and POST /jobs
answered 503 for everyone; an 82 KB .usdc became a 520 MB translated scene in Redis, kept
7 days). Real redis-server, uvicorn API and worker processes; Redis keeps only the index,
objects nothing holds are swept, objects a job holds are not."""
from __future__ import annotations

import hashlib
import json
import os
import re
import time

import httpx
import numpy as np
import pytest
import redis

from conftest import (CORNELL, DATA_ROOT, local_reference, farm_image, start_api, start_worker,
                      submit, wait_for_job)
from tessera_queue import redis_schema as rdb
from tessera_cli.embedded import redis_server

MiB = 1 << 20
FORM = dict(width=32, height=32, spp=2, seed=1, max_depth=8, tile_size=16)


def wait_until(predicate, timeout: float, what: str, poll: float = 0.05):
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, what
        time.sleep(poll)
    return value


def object_path(client: redis.Redis, digest: str):
    """Where the farm of `client` keeps object `digest` (tessera_queue.data_store layout)."""
    sid = client.get(rdb.DATA_STORE_ID)
    assert sid is not None, "the farm has no data store"
    return DATA_ROOT / sid.decode() / "objects" / digest[:2] / digest


def test_uploads_do_not_fill_the_queues_redis(tmp_path):
    """Six 1 MiB files into a Redis with 4 MiB of room (the issue's six 250 MiB files into
    the deploy maxmemory, scaled down): before, the fourth PUT answered 503 "job store is
    full" and so did POST /jobs; now all six are stored, Redis grows by their index only
    (all its keys hold under 32 KiB; used_memory, with the API's connections, grows by
    under a tenth of the 6 MiB), and jobs are accepted. The bytes are the files
    named by their SHA-256 in the data directory."""
    blobs = [os.urandom(MiB) for _ in range(6)]
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        api, base = start_api(rs.url, tmp_path, user_blob_quota_bytes=str(8 * MiB),
                              max_upload_bytes=str(2 * MiB))
        try:
            with httpx.Client(base_url=base, timeout=60) as http:
                before = client.info("memory")["used_memory"]
                client.config_set("maxmemory", before + 4 * MiB)
                for data in blobs:
                    r = http.put(f"/blobs/{hashlib.sha256(data).hexdigest()}", content=data)
                    assert r.status_code == 201, (r.status_code, r.text)
                grown = client.info("memory")["used_memory"] - before
                assert grown < 6 * MiB // 10, f"Redis grew by {grown} bytes for {6 * MiB} bytes of files"
                held = sum(client.memory_usage(k) for k in client.scan_iter())
                assert held < 32 * 1024, f"Redis's keys hold {held} bytes"
                for data in blobs:
                    digest = hashlib.sha256(data).hexdigest()
                    assert object_path(client, digest).read_bytes() == data
                    assert int(client.get(rdb.blob_key(digest))) == len(data)
                # DELETE /blobs deletes the bytes at once, not at the next sweep.
                gone = hashlib.sha256(blobs[0]).hexdigest()
                assert http.delete(f"/blobs/{gone}").json()["bytes"] == MiB
                assert not object_path(client, gone).exists() and not client.exists(rdb.data_key(gone))

                # Jobs are accepted: a plain upload and a packed one, whose scene bytes
                # are not in Redis either.
                assert submit(http, CORNELL, **FORM).status_code == 201
                text = CORNELL.read_bytes()
                digest = hashlib.sha256(text).hexdigest()
                assert http.put(f"/blobs/{digest}", content=text).status_code == 201
                manifest = json.dumps({"entry": "cornell.usda", "files": {"cornell.usda": digest}})
                r = http.post("/jobs", files={"manifest": ("m.json", manifest)},
                              data={k: str(v) for k, v in FORM.items()})
                assert r.status_code == 201, r.text
                scene_hash = client.hget(rdb.job_key(r.json()["id"]), "scene_hash").decode()
                fields = client.hgetall(rdb.scene_key(scene_hash))
                assert sum(len(v) for v in fields.values()) < 256, fields.keys()
                assert object_path(client, scene_hash).stat().st_size > len(text)  # the zip
        finally:
            api.stop()
            client.close()


@pytest.mark.slow  # sweeps past a 2 s retention: about 10 s
def test_unheld_objects_are_swept_held_ones_kept(tmp_path):
    """Scene retention 2 s, a sweep every 0.2 s, no worker: an uploaded file whose
    retention passed is deleted (file and index) by a sweep, the scene of a queued job
    stays through later sweeps although its retention passed too (control), and goes
    once the job is cancelled. Synchronised on Redis's expiry of the keys and on the
    sweep counters (the bytes they count deleted are the files' sizes)."""
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        api, base = start_api(rs.url, tmp_path, scene_retention="2", data_sweep_seconds="0.2")
        try:
            with httpx.Client(base_url=base, timeout=60) as http:
                job = submit(http, CORNELL, **FORM).json()["id"]
                scene_hash = client.hget(rdb.job_key(job), "scene_hash").decode()
                scene_file = object_path(client, scene_hash)
                assert scene_file.read_bytes() == CORNELL.read_bytes()
                lone = os.urandom(4096)
                h_lone = hashlib.sha256(lone).hexdigest()
                assert http.put(f"/blobs/{h_lone}", content=lone).status_code == 201

                wait_until(lambda: not client.exists(rdb.blob_key(h_lone)), 30, "the upload never expired")
                wait_until(lambda: client.hget(rdb.STATS, "data_evicted"), 30,
                           "the expired upload was never swept")
                assert int(client.hget(rdb.STATS, "data_evicted_bytes")) == len(lone)
                assert not object_path(client, h_lone).exists() and not client.exists(rdb.data_key(h_lone))
                # The scene's retention (set when the job was submitted) has passed too.
                wait_until(lambda: not client.exists(rdb.preflight_key(scene_hash, ".usda")), 30,
                           "the pre-flight result never expired")
                sweeps = int(client.hget(rdb.STATS, "data_sweeps"))
                wait_until(lambda: int(client.hget(rdb.STATS, "data_sweeps")) >= sweeps + 2, 30,
                           "no sweep ran")
                assert scene_file.read_bytes() == CORNELL.read_bytes(), "a queued job's scene was swept"
                assert client.exists(rdb.data_key(scene_hash))
                assert int(client.hget(rdb.STATS, "data_evicted")) == 1

                assert http.delete(f"/jobs/{job}").status_code == 200
                wait_until(lambda: not scene_file.exists(), 30, "the released scene was never swept")
                assert not client.exists(rdb.data_key(scene_hash))
                assert int(client.hget(rdb.STATS, "data_evicted")) == 2
                assert int(client.hget(rdb.STATS, "data_evicted_bytes")) == len(lone) + len(CORNELL.read_bytes())
                metrics = http.get("/metrics").text
                assert "tessera_data_evicted_total 2.0" in metrics, metrics
        finally:
            api.stop()
            client.close()


@pytest.mark.slow  # two workers and a local render: about 17 s
def test_translated_scene_is_in_the_data_store_and_translated_once(tmp_path):
    """The renderer's translated scene is an object of the data store: the scene hash in
    Redis names it by SHA-256 (before: it held the blob's bytes, 520 MB for the issue's
    10^7 triangles). A second job of the scene, on another worker with nothing cached,
    renders from it without translating again, and its image is the local render's."""
    from tessera_renderer import scene_blob

    version = f"v{scene_blob.BLOB_VERSION}.{scene_blob.TRANSLATOR_VERSION}"
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        api, base = start_api(rs.url, tmp_path)
        workers = [start_worker(rs.url, "translate-a", tmp_path)]
        try:
            with httpx.Client(base_url=base, timeout=60) as http:
                first = submit(http, CORNELL, **FORM).json()["id"]
                wait_for_job(http, first, processes=workers, expect="done")
                scene_hash = client.hget(rdb.job_key(first), "scene_hash").decode()
                translated = client.hget(rdb.scene_key(scene_hash), rdb.translated_field(version))
                assert translated is not None
                assert re.fullmatch(rb"[0-9a-f]{64}", translated), \
                    f"the scene hash holds {len(translated)} bytes of translated scene"
                fields = client.hgetall(rdb.scene_key(scene_hash))
                assert sum(len(v) for v in fields.values()) < 512
                blob = object_path(client, translated.decode()).read_bytes()
                assert blob.startswith(scene_blob.MAGIC)
                assert hashlib.sha256(blob).hexdigest() == translated.decode()
                assert int(client.hget(rdb.STATS, "scene_translations")) == 1

                workers[0].stop()
                workers.append(start_worker(rs.url, "translate-b", tmp_path))
                form = {**FORM, "seed": 2}
                second = submit(http, CORNELL, **form).json()["id"]
                wait_for_job(http, second, processes=workers[1:], expect="done")
                assert int(client.hget(rdb.STATS, "scene_translations")) == 1
                expected = local_reference(form)
                actual = farm_image(http, second, tmp_path)
                assert np.array_equal(actual.view(np.uint32), expected.view(np.uint32))
        finally:
            for proc in (*workers, api):
                proc.stop()
            client.close()


def test_a_worker_without_a_usable_data_directory_refuses_to_start(tmp_path):
    """A worker that cannot write to the data directory would fail every scene it took:
    it says so once and exits. Control: the same worker with a writable directory
    starts (its heartbeat appears)."""
    import subprocess
    import sys

    from conftest import clean_env

    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with redis_server(str(tmp_path)) as rs:
        env = clean_env(REDIS_URL=rs.url, TESSERA_DATA_DIR=str(blocker / "data"))
        proc = subprocess.run([sys.executable, "-m", "tessera_worker", "--name", "no-data"],
                              env=env, capture_output=True, text=True, timeout=120)
        assert proc.returncode != 0
        assert f"cannot write to the data directory {blocker / 'data'}" in proc.stderr, proc.stderr
        worker = start_worker(rs.url, "with-data", tmp_path)  # the session's directory
        worker.stop()


def test_the_store_checks_what_it_reads_and_keeps_what_is_held(redis_client, tmp_path):
    """data_store on a real Redis, in-process: a held object survives an eviction, an
    eviction whose file a writer recorded again meanwhile puts the file back (the race
    the index-first order closes), an unheld one goes (file and index), and bytes that
    no longer match their name are refused on read."""
    from tessera_queue.data_store import DataStore, ObjectMissing

    store = DataStore(tmp_path / "data", redis_client)
    data = os.urandom(1000)
    digest = hashlib.sha256(data).hexdigest()
    holder = "tessera:test:holder"
    redis_client.set(holder, 1)
    with redis_client.pipeline() as pipe:
        store.hold(pipe, digest, len(data), holder)
        pipe.execute()
    store.write_bytes(digest, data)
    assert store.evict_if_unheld(digest) is None and store.read_bytes(digest) == data

    redis_client.delete(holder)
    # The file's deletion after a writer recorded the object again (its index is back).
    assert store._remove_file(digest) == 0 and store.read_bytes(digest) == data
    assert store.evict_if_unheld(digest) == len(data)
    assert not store.path(digest).exists() and not redis_client.exists(rdb.data_key(digest))
    with pytest.raises(ObjectMissing, match="missing from the farm's data directory"):
        store.read_bytes(digest)

    store.write_bytes(digest, data)
    store.path(digest).write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    with pytest.raises(ObjectMissing, match="does not match its SHA-256"):
        store.read_bytes(digest)
    with pytest.raises(ObjectMissing, match="does not match its SHA-256"):
        store.copy_to(digest, tmp_path / "copy")
    assert not (tmp_path / "copy").exists()


@pytest.mark.slow  # a worker and a local render: about 15 s
def test_a_farm_upgraded_from_bytes_in_redis_renders_what_it_stored(tmp_path):
    """A Redis written before the data store: a scene's bytes in its hash (field data),
    its translated scene as a field's value, an uploaded file's bytes in its index. After
    the upgrade a queued job of that scene renders the local render's image from the old
    translated scene (translated no more); a job at another time code, which needs the
    scene's bytes, has its worker move them into the data store; the API moves the file
    when a manifest uses it."""
    from tessera_base.protocol import JobSpec, RenderSettings
    from tessera_renderer import scene_blob
    from tessera_service.store import JobStore

    version = f"v{scene_blob.BLOB_VERSION}.{scene_blob.TRANSLATOR_VERSION}"
    scene = CORNELL.read_bytes()
    scene_hash = hashlib.sha256(scene).hexdigest()
    layer = scene + b"\n# uploaded before the data store\n"
    layer_hash = hashlib.sha256(layer).hexdigest()
    with redis_server(str(tmp_path)) as rs:
        client = redis.Redis.from_url(rs.url)
        key = rdb.scene_key(scene_hash)
        client.hset(key, mapping={"name": "cornell.usda", "data": scene, "retention": 3600,
                                  rdb.translated_field(version): scene_blob.translate_to_blob(CORNELL)})
        client.expire(key, 3600)
        client.set(rdb.blob_key(layer_hash), layer, ex=3600)
        client.sadd(rdb.blob_owners_key(layer_hash), "alice")
        client.hset(rdb.blob_usage_key("alice"), layer_hash, len(layer))
        api, base = start_api(rs.url, tmp_path, api_tokens="alice:alice-token")
        worker = start_worker(rs.url, "upgraded", tmp_path)
        try:
            with httpx.Client(base_url=base, timeout=60,
                              headers={"Authorization": "Bearer alice-token"}) as http:
                spec = JobSpec(job_id="a" * 32, scene_hash=scene_hash, scene_name="cornell.usda",
                               settings=RenderSettings(**FORM))
                JobStore(client).create_job(spec, [], owner="alice")
                wait_for_job(http, spec.job_id, processes=[worker, api], expect="done")
                actual = farm_image(http, spec.job_id, tmp_path)
                assert np.array_equal(actual.view(np.uint32), local_reference(FORM).view(np.uint32))
                assert client.hget(rdb.STATS, "scene_translations") is None  # the old blob served
                # Another time code needs a translation of its own, from the scene's bytes.
                frame = JobSpec(job_id="b" * 32, scene_hash=scene_hash, scene_name="cornell.usda",
                                settings=RenderSettings(**FORM, frame=1.0))
                JobStore(client).create_job(frame, [], owner="alice")
                wait_for_job(http, frame.job_id, processes=[worker, api], expect="done")
                assert int(client.hget(rdb.STATS, "scene_translations")) == 1
                assert not client.hexists(key, "data")
                assert object_path(client, scene_hash).read_bytes() == scene

                manifest = json.dumps({"entry": "cornell.usda", "files": {"cornell.usda": layer_hash}})
                r = http.post("/jobs", files={"manifest": ("m.json", manifest)},
                              data={k: str(v) for k, v in FORM.items()})
                assert r.status_code == 201, r.text
                assert int(client.get(rdb.blob_key(layer_hash))) == len(layer)
                assert object_path(client, layer_hash).read_bytes() == layer
        finally:
            for proc in (worker, api):
                proc.stop()
            client.close()
