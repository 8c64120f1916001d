"""The job settings subdivision_level and dicing_rate: the farm refines subdivision surfaces
at the job's level, or dices them to the job's camera and frame, the image equals a local
render of the same settings bit for bit, and each one's translation is shared as its own
blob (never the default level's)."""
from __future__ import annotations

import numpy as np

from conftest import api_client, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base.protocol import RenderSettings
from tessera_queue import redis_schema as rdb
from tessera_renderer import load_scene
from tessera_renderer.usd.dicing import Dicing

# A Catmull-Clark cube (no subdivisionScheme authored: the schema's fallback) in front of
# the camera, lit by a sphere light; refined it is a rounded blob, its cage a cube.
CUBE = """#usda 1.0
(upAxis = "Y")
def Camera "Camera" {
    double3 xformOp:translate = (0, 0, 4)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def SphereLight "Key" {
    float inputs:radius = 0.3
    float inputs:intensity = 20
    double3 xformOp:translate = (1.5, 2, 2)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Mesh "Cube" {
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]
    point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1),
                        (-1, -1, -1), (1, -1, -1)]
}
"""
FORM = {"width": 48, "height": 48, "spp": 4, "tile_size": 24, "integrator": "path"}


def test_farm_renders_the_jobs_subdivision_level_as_a_local_render_does(redis_server, tmp_path):
    scene = tmp_path / "subdiv_cube.usda"
    scene.write_text(CUBE)
    local_at = {level: local.render_image(load_scene(scene, subdivision_level=level),
                                          RenderSettings(**FORM), progress=False, variance=False).rgba
                for level in (0, 2)}
    # The level matters: the cage's silhouette is not the refined surface's.
    assert np.count_nonzero(np.any(local_at[0] != local_at[2], axis=-1)) > 100
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        worker = start_worker(farm.redis_url, "subdiv-0", farm.log_dir)
        try:
            for level in (0, None):
                r = submit(farm, scene, **FORM, **({} if level is None else {"subdivision_level": level}))
                assert r.status_code == 201, r.text
                job = r.json()["id"]
                status = wait_for_job(farm, job, timeout=120, processes=[worker], expect="done")
                assert status["settings"]["subdivision_level"] == level
                image = farm_image(farm, job, tmp_path)
                expected = local_at[0 if level == 0 else 2]
                assert np.array_equal(image.view(np.uint32), expected.view(np.uint32)), \
                    f"level {level}: {np.count_nonzero(image != expected)} values differ"
            # Dicing: the cube's cage edges span ~77 pixels of the 48-pixel frame (edge 2 at
            # depth ~3), so a 1-pixel rate asks for level 7, held to the job's maximum of 3:
            # 2 x 4^3 triangles per quad. Every tile's worker dices for the whole frame.
            diced = dict(dicing_rate=1.0, dicing_max_level=3)
            scene_diced = load_scene(scene, dicing=Dicing.requested(1.0, 3, None, (48, 48)))
            assert scene_diced.num_triangles == 2 * 4 ** 3 * 6
            expected = local.render_image(scene_diced, RenderSettings(**FORM, **diced), progress=False,
                                          variance=False).rgba
            assert np.count_nonzero(np.any(expected != local_at[2], axis=-1)) > 0  # level 3 is not 2
            r = submit(farm, scene, **FORM, **diced)
            assert r.status_code == 201, r.text
            job = r.json()["id"]
            status = wait_for_job(farm, job, timeout=120, processes=[worker], expect="done")
            assert status["settings"]["dicing_rate"] == 1.0
            image = farm_image(farm, job, tmp_path)
            assert np.array_equal(image.view(np.uint32), expected.view(np.uint32)), \
                f"diced: {np.count_nonzero(image != expected)} values differ"
            # Each level's (and dicing's) translation is its own blob in the scene's hash.
            fields = [f.decode() for key in farm_redis_keys(farm) for f in key]
            assert any(f.startswith("translated:") and f.endswith(".subdiv0") for f in fields), fields
            assert any(f.startswith("translated:") and ".dice" in f for f in fields), fields
            assert any(f.startswith("translated:") and ".subdiv" not in f and ".dice" not in f
                       for f in fields), fields
        finally:
            worker.stop()
        r = submit(farm, scene, **FORM, subdivision_level=7)
        assert r.status_code == 422 and "subdivision_level" in r.text, r.text


def farm_redis_keys(farm):
    import redis

    client = redis.Redis.from_url(farm.redis_url)
    return [client.hkeys(key) for key in client.scan_iter(rdb.scene_key("*"))]
