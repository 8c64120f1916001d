"""A heterogeneous volume on the farm (docs/media.md): `tessera submit` packs the scene's
VDB file with its layer, the file reaches the farm through the blob store once, and the
farm's image of a small smoke cloud equals a local render bit for bit."""
from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import clean_env, start_api, start_worker
from tessera_base import images
from tessera_queue import redis_schema as rdb
from tessera_renderer import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "renderer" / "usd"))
from test_volumes import CAMERA, LIGHTS, smoke_grid, volume_prim, write_vdb  # noqa: E402

pytestmark = pytest.mark.slow  # a real farm and two CLI renders: about 25 s

ARGS = ["--res", "16x16", "--spp", "4", "--seed", "3", "--max-depth", "8", "--tile", "8", "--integrator", "path"]


def tessera(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tessera", *args], env=clean_env(),
                          capture_output=True, text=True, timeout=300)


def test_farm_renders_a_vdb_cloud_as_a_local_render_does(redis_server, redis_client, tmp_path):
    shot = tmp_path / "shot"
    (shot / "vdb").mkdir(parents=True)
    # A lumpy cloud: the soft ball times noise, so tracking meets null collisions.
    rng = np.random.default_rng(4)
    write_vdb(shot / "vdb" / "cloud.vdb", {"density": smoke_grid(20) * rng.uniform(0.3, 1.0, (20, 20, 20))},
              0.12, origin=(-10, -10, -10))
    camera = CAMERA.replace("float focalLength = 500", "float focalLength = 60")
    scene = shot / "cloud.usda"
    scene.write_text("#usda 1.0\n" + camera + LIGHTS
                     + volume_prim({"density": "vdb/cloud.vdb"}, (0, 0, -10)))
    local_scene = load_scene(scene)
    assert local_scene._core.has_media and local_scene.warnings == [], local_scene.warnings
    logs = tmp_path / "logs"
    logs.mkdir()
    api_proc, base = start_api(redis_server, logs)
    worker = start_worker(redis_server, "w-volumes", logs)
    try:
        out = tmp_path / "farm.exr"
        proc = tessera("submit", str(scene), "--server", base, "--wait", "-o", str(out), *ARGS)
        assert proc.returncode == 0, proc.stderr + api_proc.log() + worker.log()
        digest = hashlib.sha256((shot / "vdb" / "cloud.vdb").read_bytes()).hexdigest()
        assert redis_client.exists(rdb.blob_key(digest)), "the VDB did not go through the blob store"
        local = tmp_path / "local.exr"
        proc_local = tessera("render", str(scene), "-o", str(local), "-q", "--threads", "1", *ARGS)
        assert proc_local.returncode == 0, proc_local.stderr
        farm_img, local_img = images.read_exr(out), images.read_exr(local)
        assert np.array_equal(farm_img.view(np.uint32), local_img.view(np.uint32)), \
            f"{np.count_nonzero(farm_img != local_img)} values differ"
        assert farm_img[..., :3].max() > 0
    finally:
        worker.stop()
        api_proc.stop()
