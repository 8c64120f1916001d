"""`tessera submit` of a loose layer packs its dependencies and uploads only the files the
farm lacks (real redis-server, uvicorn and a worker): the farm's image equals the local
render bit for bit, a second submit with one changed texture uploads only that texture,
and the blob endpoints refuse wrong hashes, oversized files and escaping paths."""
from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import httpx
import numpy as np
import pytest

from conftest import clean_env, start_api, start_worker, submit, wait_for_job
from tessera_base import images
from tessera_queue import redis_schema as rdb
from tessera_service.store import JobStore
from test_bundles import MESH, layer
from test_packing import PROJECT_FILES, SCENES, make_project, write_texture

UPLOAD_LIMIT = 8 << 20
RETENTION = 5000
# The shot's meshes are subdivision surfaces (the schema's fallback) seen by a camera: the
# level is given, since `tessera render` would otherwise dice them and the farm does not.
ARGS = ["--res", "24x16", "--spp", "4", "--seed", "5", "--max-depth", "6", "--tile", "8",
        "--subdivision-level", "2"]


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("packing-farm")
    api_proc, base = start_api(redis_server, logs, max_upload_bytes=UPLOAD_LIMIT,
                               scene_retention=RETENTION)
    worker = start_worker(redis_server, "w-packing", logs)
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes = [api_proc, worker]
        yield client
    worker.stop()
    api_proc.stop()


def blob_count(redis_client) -> int:
    return sum(1 for _ in redis_client.scan_iter(rdb.blob_key("*")))


def tessera(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tessera", *args], env=clean_env(),
                          capture_output=True, text=True, timeout=300)


def uploaded(stderr: str) -> tuple[int, int, int]:
    """(files packed, files uploaded, bytes uploaded) from the client's report line."""
    m = re.search(r"packed (\d+) file\(s\), .*; uploaded (\d+) \((\d+) bytes", stderr)
    assert m, stderr
    return int(m[1]), int(m[2]), int(m[3])


def test_submit_packs_the_project_and_the_farm_renders_what_render_does(farm, redis_client, tmp_path):
    shot = make_project(tmp_path / "proj")
    # Control: the shot alone is refused by the farm's sandbox (its layers lie in ../).
    r = submit(farm, shot, width=8, height=8, spp=1)
    assert r.status_code == 422 and "../lib/lights.usda" in r.json()["detail"], r.text
    before = blob_count(redis_client)
    out = tmp_path / "farm.exr"
    proc = tessera("submit", str(shot), "--server", str(farm.base_url), "--wait", "-o", str(out), *ARGS)
    assert proc.returncode == 0, proc.stderr
    assert "warning: not found, not packed: ../textures/missing.png (in shot.usda)" in proc.stderr
    files = {rel: tmp_path / "proj" / rel for rel in PROJECT_FILES}
    total = sum(p.stat().st_size for p in files.values())
    assert uploaded(proc.stderr) == (6, 6, total)
    assert blob_count(redis_client) == before + 6
    data = JobStore(redis_client).data  # the session's data directory, as the API's
    for rel, path in files.items():   # stored under their hash, with the scene retention
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        key = rdb.blob_key(digest)
        assert int(redis_client.get(key)) == path.stat().st_size, rel  # Redis: the index only
        assert data.read_bytes(digest) == path.read_bytes(), rel
        assert 0 < redis_client.ttl(key) <= RETENTION
    local = tmp_path / "local.exr"
    proc_local = tessera("render", str(shot), "-o", str(local), "-q", "--threads", "1", *ARGS)
    assert proc_local.returncode == 0, proc_local.stderr
    np.testing.assert_array_equal(images.read_exr(out), images.read_exr(local))

    # One changed texture: only it travels, and the farm renders the new colour.
    write_texture(tmp_path / "proj" / "textures" / "t.png", (30, 60, 200))
    second = tmp_path / "farm2.exr"
    proc = tessera("submit", str(shot), "--server", str(farm.base_url), "--wait", "-o", str(second), *ARGS)
    assert proc.returncode == 0, proc.stderr
    assert uploaded(proc.stderr) == (6, 1, (tmp_path / "proj" / "textures" / "t.png").stat().st_size)
    assert blob_count(redis_client) == before + 7
    proc_local = tessera("render", str(shot), "-o", str(local), "-q", "--threads", "1", *ARGS)
    assert proc_local.returncode == 0, proc_local.stderr
    np.testing.assert_array_equal(images.read_exr(second), images.read_exr(local))
    assert not np.array_equal(images.read_exr(second), images.read_exr(out))
    assert all(p.alive() for p in farm.processes)


@pytest.mark.shared_scenes
def test_a_shared_scene_with_textures_uploads_one_changed_texture(farm, tmp_path):
    """The teapot (payload, variants, 2k JPEG textures): the first submit uploads every file,
    the second, after one texture changed, only that texture."""
    source = SCENES / "usdwg_teapot"
    if not source.exists():
        pytest.skip(f"{source} is not on this machine")
    teapot = tmp_path / "teapot"
    shutil.copytree(source, teapot)
    scene = teapot / "Teapot.usd"
    proc = tessera("submit", str(scene), "--server", str(farm.base_url), "--res", "8x8", "--spp", "1")
    assert proc.returncode == 0, proc.stderr
    files, count, sent = uploaded(proc.stderr)
    textures = sorted((teapot / "textures").rglob("*.jpg"))
    assert files == count == 8 and sent == sum(p.stat().st_size for p in teapot.rglob("*")
                                               if p.suffix in (".usd", ".jpg"))
    assert proc.stderr.count("warning: not found, not packed: ./cards/") == 12
    print(f"teapot: {files} files, {sent} bytes on the first submit")
    from OpenImageIO import ImageBuf
    changed = textures[0]   # repainted at its own resolution (inverted)
    changed.chmod(0o644)    # the shared copy is read-only
    pixels = ImageBuf(str(changed)).get_pixels()
    ImageBuf(np.ascontiguousarray((255 * (1.0 - pixels)).round().astype(np.uint8))).write(str(changed))
    proc = tessera("submit", str(scene), "--server", str(farm.base_url), "--res", "8x8", "--spp", "1")
    assert proc.returncode == 0, proc.stderr
    assert uploaded(proc.stderr) == (8, 1, changed.stat().st_size)
    print(f"teapot: 1 file, {changed.stat().st_size} bytes on the second submit ({changed.name} changed)")


def _put(farm, data: bytes, digest: str | None = None) -> httpx.Response:
    return farm.put(f"/blobs/{digest or hashlib.sha256(data).hexdigest()}", content=data)


def _post_manifest(farm, manifest: dict) -> httpx.Response:
    return farm.post("/jobs", files={"manifest": ("m.json", json.dumps(manifest).encode())},
                     data={"width": "8", "height": "8", "spp": "1"})


def test_blobs_are_verified_limited_and_manifests_stay_inside_the_bundle(farm, redis_client):
    good = layer(MESH).encode()
    digest = hashlib.sha256(good).hexdigest()
    wrong = hashlib.sha256(b"something else").hexdigest()
    r = _put(farm, good, wrong)
    assert r.status_code == 422 and "nothing was stored" in r.json()["detail"]
    assert not redis_client.exists(rdb.blob_key(wrong))
    assert _put(farm, b"x", "not-a-hash").status_code == 422
    big = bytes(UPLOAD_LIMIT + 1)
    r = _put(farm, big)
    assert r.status_code == 413 and not redis_client.exists(rdb.blob_key(hashlib.sha256(big).hexdigest()))
    r = _put(farm, good)
    assert r.status_code == 201 and r.json() == {"hash": digest, "size": len(good), "stored": True}
    assert _put(farm, good).json()["stored"] is False
    r = farm.post("/blobs/missing", json={"hashes": [digest, wrong]})
    assert r.status_code == 200 and r.json() == {"missing": [wrong]}

    refused = {
        "escaping path": ({"entry": "s.usda", "files": {"s.usda": digest, "../x.usda": digest}}, 422, "../x.usda"),
        "absolute path": ({"entry": "/s.usda", "files": {"/s.usda": digest}}, 422, "/s.usda"),
        "entry not packed": ({"entry": "t.usda", "files": {"s.usda": digest}}, 422, "t.usda"),
        "entry not a layer": ({"entry": "s.png", "files": {"s.png": digest}}, 422, "s.png"),
        "unknown file": ({"entry": "s.usda", "files": {"s.usda": digest, "t.png": wrong}}, 409, "t.png"),
        "not a hash": ({"entry": "s.usda", "files": {"s.usda": "abc"}}, 422, "abc"),
    }
    for label, (manifest, status, named) in refused.items():
        r = _post_manifest(farm, manifest)
        assert r.status_code == status and named in r.json()["detail"], (label, r.status_code, r.text)
    # The assembled bundle is sandboxed like any upload: a layer reaching out of it is refused.
    reaching = layer('def "R" (references = @../../secret.usda@) {}\n' + MESH).encode()
    assert _put(farm, reaching).status_code == 201
    r = _post_manifest(farm, {"entry": "a/s.usda", "files": {"a/s.usda": hashlib.sha256(reaching).hexdigest()}})
    assert r.status_code == 422 and "../../secret.usda" in r.json()["detail"], r.text
    # Many small files that together exceed the upload limit are refused before assembly.
    chunk = bytes(UPLOAD_LIMIT // 3 + 1)
    parts = {}
    for i in range(3):
        data = chunk[:-1] + bytes([i + 1])
        assert _put(farm, data).status_code == 201
        parts[f"d{i}.bin"] = hashlib.sha256(data).hexdigest()
    r = _post_manifest(farm, {"entry": "s.usda", "files": {"s.usda": digest, **parts}})
    assert r.status_code == 422 and "upload limit" in r.json()["detail"], r.text
    # Neither file nor manifest, or both.
    assert farm.post("/jobs", data={"spp": "1"}).status_code == 422
    # A valid manifest renders.
    r = _post_manifest(farm, {"entry": "s.usda", "files": {"s.usda": digest}})
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes)
    assert status["state"] == "done" and status["scene_name"] == "s.usda.zip", status


def test_a_packed_submit_works_under_the_farms_redis_users(tmp_path):
    """On Redis with the farm's ACL users (tessera_service.redis_acl): the API stores and
    assembles blobs, the worker renders the assembled scene, and the worker user cannot
    read the blobs (only the API needs them)."""
    import redis

    from conftest import start_api, start_worker
    from tessera_cli.embedded import redis_server
    from tessera_service.redis_acl import Credentials

    shot = make_project(tmp_path / "proj")
    (tmp_path / "acl").mkdir()
    with redis_server(str(tmp_path / "acl"), credentials=Credentials.generate()) as local:
        api, base = start_api(local.url, tmp_path)
        worker = start_worker(local.worker_url, "acl-packing", tmp_path)
        try:
            proc = tessera("submit", str(shot), "--server", base, "--wait", "-o", str(tmp_path / "f.exr"), *ARGS)
            assert proc.returncode == 0, proc.stderr + api.log() + worker.log()
            assert uploaded(proc.stderr)[:2] == (6, 6)
        finally:
            worker.stop()
            api.stop()
        digest = hashlib.sha256((tmp_path / "proj" / "top.usda").read_bytes()).hexdigest()
        as_api = redis.Redis.from_url(local.url)
        as_worker = redis.Redis.from_url(local.worker_url)
        try:
            assert as_api.exists(rdb.blob_key(digest))   # the control: it is there
            with pytest.raises(redis.ResponseError, match="(?i)no permissions"):
                as_worker.get(rdb.blob_key(digest))
        finally:
            as_api.close()
            as_worker.close()
    for p in (api, worker):
        assert "NOPERM" not in p.log_path.read_text(errors="replace"), p.log(80)


@pytest.mark.shared_scenes
def test_the_mini_car_kit_renders_on_the_farm_as_it_does_locally(farm, tmp_path):
    """The issue's example: vehicleVariants.usda references ../../../wheels/...; submitted
    as a loose layer it is packed from the kit's folder, and the farm's image equals the
    local (trusted) render bit for bit."""
    scene = SCENES / "usdwg_mini_car_kit" / "USD_Mini_Car_Kit" / "assets" / "vehicles" / "vehicleVariants.usda"
    if not scene.exists():
        pytest.skip(f"{scene} is not on this machine")
    out, local = tmp_path / "farm.exr", tmp_path / "local.exr"
    proc = tessera("submit", str(scene), "--server", str(farm.base_url), "--wait", "-o", str(out), *ARGS)
    assert proc.returncode == 0, proc.stderr
    assert uploaded(proc.stderr)[0] == 53 and "USD_Mini_Car_Kit)" in proc.stderr
    proc = tessera("render", str(scene), "-o", str(local), "-q", "--threads", "1", *ARGS)
    assert proc.returncode == 0, proc.stderr
    farm_image, local_image = images.read_exr(out), images.read_exr(local)
    np.testing.assert_array_equal(farm_image, local_image)
    assert farm_image[..., 3].any()   # the vehicle is in the picture
