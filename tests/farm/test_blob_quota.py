"""Packed-scene files (PUT /blobs) per user (issue 42, item 7: six 250 MiB uploads filled
the deploy Redis and POST /jobs answered 503 for everyone; blobs could not be deleted).
Real uvicorn API with two users' tokens and redis-server: an upload past the user's quota
gets 413 and stores nothing; another user's quota is their own; DELETE frees a user's
quota, and removes the bytes from Redis once no user who sent them keeps them."""
from __future__ import annotations

import hashlib
import os

import httpx
import pytest
import redis

from conftest import start_api
from tessera.upload import UploadReport, _upload_missing, file_hash
from tessera_queue import redis_schema as rdb

MiB = 1 << 20
QUOTA = 3 * MiB
A = os.urandom(2 * MiB)          # 2 MiB: fits the quota alone
B = os.urandom(MiB + MiB // 2)   # 1.5 MiB: with A, 3.5 MiB, past the quota
HA, HB = hashlib.sha256(A).hexdigest(), hashlib.sha256(B).hexdigest()


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("api"),
                           api_tokens="alice:alice-token,bob:bob-token",
                           user_blob_quota_bytes=str(QUOTA), max_upload_bytes=str(4 * MiB))
    clients = {name: httpx.Client(base_url=base, timeout=60,
                                  headers={"Authorization": f"Bearer {name}-token"})
               for name in ("alice", "bob")}
    yield clients
    for c in clients.values():
        c.close()
    proc.stop()


def test_quota_and_delete(api, redis_client: redis.Redis):
    alice, bob = api["alice"], api["bob"]
    assert alice.put(f"/blobs/{HA}", content=A).status_code == 201
    r = alice.put(f"/blobs/{HB}", content=B)
    assert r.status_code == 413, r.text
    assert "TESSERA_USER_BLOB_QUOTA_BYTES" in r.json()["detail"]
    assert f"{len(A) + len(B)} bytes" in r.json()["detail"]
    assert not redis_client.exists(rdb.blob_key(HB))  # refused: nothing stored
    # Alice's bytes already stored are not counted twice.
    again = alice.put(f"/blobs/{HA}", content=A)
    assert again.status_code == 201 and again.json()["stored"] is False
    # Bob's quota is his own.
    assert bob.put(f"/blobs/{HB}", content=B).status_code == 201

    # Deleting A frees Alice's quota and, as she alone sent it, its bytes.
    r = alice.delete(f"/blobs/{HA}")
    assert r.status_code == 200 and r.json()["bytes"] == len(A), r.text
    assert not redis_client.exists(rdb.blob_key(HA))
    assert alice.delete(f"/blobs/{HA}").status_code == 404
    r = alice.put(f"/blobs/{HB}", content=B)  # fits now (stored already by Bob)
    assert r.status_code == 201 and r.json()["stored"] is False, r.text

    # Bob deletes B: Alice, who sent it too, keeps it.
    assert bob.delete(f"/blobs/{HB}").json()["bytes"] == len(B)
    assert redis_client.exists(rdb.blob_key(HB))
    assert alice.post("/blobs/missing", json={"hashes": [HB]}).json()["missing"] == []
    assert bob.post("/blobs/missing", json={"hashes": [HB]}).json()["missing"] == [HB]

    # DELETE /blobs: all of Alice's, and the bytes with them.
    r = alice.delete("/blobs")
    assert r.status_code == 200 and r.json() == {"files": 1, "bytes": len(B), "quota": QUOTA}, r.text
    assert not redis_client.exists(rdb.blob_key(HB))
    assert not redis_client.exists(rdb.blob_owners_key(HB))


@pytest.mark.slow  # its own API with three users: about 3 s
def test_uploads_in_flight_are_bounded_per_user_and_in_total(redis_server, tmp_path):
    """Issue 42, item 6: PUT /blobs had no bound on uploads in flight, so one user's slow
    uploads each held a temporary file of up to the upload limit for as long as they liked.
    Now a user's upload past TESSERA_USER_UPLOAD_CONCURRENCY, or anyone's past
    TESSERA_UPLOAD_CONCURRENCY, gets 429 with Retry-After, naming the setting; another user
    is served while one is at their bound, and a finished upload frees its slot. (Before,
    the second upload was simply served: the wait for a 429 below ran out.)"""
    import threading

    proc, base = start_api(redis_server, tmp_path, api_tokens="alice:a-tok,bob:b-tok,carol:c-tok",
                           user_upload_concurrency="1", upload_concurrency="2", max_upload_bytes=str(4 * MiB))
    clients = {n: httpx.Client(base_url=base, timeout=60, headers={"Authorization": f"Bearer {n[0]}-tok"})
               for n in ("alice", "bob", "carol")}
    release = threading.Event()
    body = os.urandom(MiB)
    digest = hashlib.sha256(body).hexdigest()

    def slow_body():
        yield body[:1024]
        release.wait(60)  # held in flight until the test lets go
        yield body[1024:]

    results = {}

    def slow_put(name):
        # A client of its own: sharing one with the polling thread can keep this request
        # from being sent while the other thread's requests go out.
        with httpx.Client(base_url=base, timeout=60, headers=clients[name].headers) as own:
            results[name] = own.put(f"/blobs/{digest}", content=slow_body()).status_code

    def refused(name: str, setting: str) -> bool:
        """Polls (bounded) until `name`'s small upload is refused for `setting`: the slow
        upload holds its slot from when the API has read its headers."""
        small = os.urandom(1024)
        for _ in range(200):
            r = clients[name].put(f"/blobs/{hashlib.sha256(small).hexdigest()}", content=small)
            if r.status_code == 429:
                assert setting in r.json()["detail"] and r.headers["retry-after"] == "1", r.text
                return True
            assert r.status_code == 201, r.text
            release.wait(0.05)
        return False

    threads = [threading.Thread(target=slow_put, args=(n,)) for n in ("alice", "carol")]
    try:
        threads[0].start()
        assert refused("alice", "TESSERA_USER_UPLOAD_CONCURRENCY")
        small = os.urandom(1024)  # another user is served beside alice's upload
        assert clients["bob"].put(f"/blobs/{hashlib.sha256(small).hexdigest()}", content=small).status_code == 201
        threads[1].start()  # carol's slow upload fills the farm's two slots
        assert refused("bob", "TESSERA_UPLOAD_CONCURRENCY")
        # `tessera submit`'s uploader waits as Retry-After says instead of failing: its 429
        # is seen by a response hook, then the slots are freed and its upload goes through.
        seen = []
        layer = tmp_path / "layer.usda"
        layer.write_bytes(b"#usda 1.0\n# " + os.urandom(16).hex().encode() + b"\n")
        report = UploadReport()
        with httpx.Client(base_url=base, timeout=60, headers=clients["bob"].headers,
                          event_hooks={"response": [lambda r: seen.append(r.status_code)]}) as hooked:
            uploader = threading.Thread(target=_upload_missing, args=(
                hooked, {"layer.usda": layer}, {"layer.usda": file_hash(layer)}, report))
            uploader.start()
            for _ in range(400):
                if 429 in seen:
                    break
                release.wait(0.05)
            assert 429 in seen, seen
            release.set()
            uploader.join(60)
        assert report.uploaded == ["layer.usda"], (seen, report)
        for t in threads:
            t.join(60)
        assert results == {"alice": 201, "carol": 201}
        small = os.urandom(1024)  # alice's slot is free again
        assert clients["alice"].put(f"/blobs/{hashlib.sha256(small).hexdigest()}", content=small).status_code == 201
    finally:
        release.set()
        for t in threads:
            t.join(60)
        for c in clients.values():
            c.close()
        proc.stop()
