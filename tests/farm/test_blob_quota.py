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
