"""The job setting camera: the farm renders through the named Camera prim, bit for bit as a
local render through it does, translated into a blob of its own; a camera the scene lacks
is refused at submission, naming the scene's cameras."""
from __future__ import annotations

import numpy as np

from conftest import api_client, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene
from test_farm_subdivision import farm_redis_keys

# Two cameras: the RenderSettings' /Cams/Front and an orthographic /Cams/Top, shifted.
SCENE = """#usda 1.0
(upAxis = "Y"
renderSettingsPrimPath = "/Render/Settings")
def Scope "Render" {
    def RenderSettings "Settings" {
        rel camera = </Cams/Front>
        uniform int2 resolution = (48, 48)
    }
}
def Scope "Cams" {
    def Camera "Front" {
        double3 xformOp:translate = (0, 0.5, 5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Camera "Top" {
        token projection = "orthographic"
        float horizontalAperture = 40
        float verticalAperture = 40
        float horizontalApertureOffset = 5
        double3 xformOp:translate = (0, 6, 0)
        float xformOp:rotateX = -90
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
    }
}
def SphereLight "Key" {
    float inputs:radius = 0.3
    float inputs:intensity = 30
    double3 xformOp:translate = (1.5, 2.5, 1.5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Mesh "Floor" {
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-3, 0, -3), (-3, 0, 3), (3, 0, 3), (3, 0, -3)]
}
def Sphere "Ball" {
    double radius = 0.7
    double3 xformOp:translate = (0.4, 0.7, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""
FORM = {"spp": 4, "tile_size": 24, "integrator": "path"}


def test_farm_renders_through_the_jobs_camera_as_a_local_render_does(redis_server, tmp_path):
    scene = tmp_path / "two_cameras.usda"
    scene.write_text(SCENE)
    settings = RenderSettings(width=48, height=48, **FORM)
    local_through = {cam: local.render_image(load_scene(scene, camera=cam), settings, progress=False,
                                             variance=False).rgba
                     for cam in (None, "/Cams/Top")}
    # The camera matters: the orthographic top view is another image.
    assert np.count_nonzero(np.any(local_through[None] != local_through["/Cams/Top"], axis=-1)) > 500
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        worker = start_worker(farm.redis_url, "camera-0", farm.log_dir)
        try:
            for cam in ("/Cams/Top", None):
                r = submit(farm, scene, **FORM, **({} if cam is None else {"camera": cam}))
                assert r.status_code == 201, r.text
                job = r.json()["id"]
                status = wait_for_job(farm, job, timeout=120, processes=[worker], expect="done")
                assert status["settings"]["camera"] == cam
                image = farm_image(farm, job, tmp_path)
                expected = local_through[cam]
                assert np.array_equal(image.view(np.uint32), expected.view(np.uint32)), \
                    f"camera {cam}: {np.count_nonzero(image != expected)} values differ"
            fields = [f.decode() for key in farm_redis_keys(farm) for f in key]
            assert any(f.startswith("translated:") and ".cam" in f for f in fields), fields
            assert any(f.startswith("translated:") and ".cam" not in f for f in fields), fields
        finally:
            worker.stop()
        r = submit(farm, scene, **FORM, camera="/Cams/Side")
        assert r.status_code == 422, r.text
        assert "camera /Cams/Side is not a Camera prim of the scene (its cameras: /Cams/Front, /Cams/Top)" \
            in r.json()["detail"], r.text
        r = submit(farm, scene, **FORM, camera="Cams/Top")  # not a prim path: refused before inspecting
        assert r.status_code == 422 and "camera" in r.text, r.text
