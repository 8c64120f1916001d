"""Motion blur on the farm: the job settings frame and shutter. A moving scene renders on
the farm bit for bit as locally (path, and bdpt whose light subpaths and splats share each
camera sample's instant), each time setting translated into a blob of its own; a bad
shutter is refused at submission, naming the field."""
from __future__ import annotations

import numpy as np

from conftest import api_client, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene
from tessera_renderer.scene_blob import format_tag
from test_farm_subdivision import farm_redis_keys

# A ball keyed to cross the view between frames 1 and 3, a camera whose shutter spans a
# whole frame around the render time.
SCENE = """#usda 1.0
(upAxis = "Y"
startTimeCode = 1
endTimeCode = 3
renderSettingsPrimPath = "/Render/Settings")
def Scope "Render" {
    def RenderSettings "Settings" {
        rel camera = </Cam>
        uniform int2 resolution = (48, 48)
    }
}
def Camera "Cam" {
    float shutter:open = -0.5
    float shutter:close = 0.5
    double3 xformOp:translate = (0, 0.8, 5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
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
    double radius = 0.5
    double3 xformOp:translate.timeSamples = {1: (-1.5, 0.5, 0), 3: (1.5, 0.5, 0)}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""


def _local(scene, form, **load):
    settings = RenderSettings(width=48, height=48, **form)
    return local.render_image(load_scene(scene, **load), settings, progress=False, variance=False).rgba


def test_farm_renders_motion_blur_and_frames_as_a_local_render_does(redis_server, tmp_path):
    scene = tmp_path / "moving_ball.usda"
    scene.write_text(SCENE)
    jobs = [({"spp": 8, "tile_size": 24, "integrator": "path"}, {}),
            ({"spp": 4, "tile_size": 24, "integrator": "bdpt"}, {}),
            ({"spp": 8, "tile_size": 24, "integrator": "path"}, {"frame": 2.5, "shutter": (0.0, 0.25)})]
    expected = [_local(scene, form, **time) for form, time in jobs]
    # Time matters: the blurred frame 1 and the short shutter at frame 2.5 are other images,
    # and a still frame differs from both.
    still = _local(scene, jobs[0][0], shutter=(0, 0))
    for a, b in ((expected[0], expected[2]), (expected[0], still)):
        assert np.count_nonzero(np.any(a != b, axis=-1)) > 100
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        worker = start_worker(farm.redis_url, "motion-0", farm.log_dir)
        try:
            for (form, time), want in zip(jobs, expected):
                extra = {}
                if "frame" in time:
                    extra = {"frame": time["frame"], "shutter": ",".join(map(str, time["shutter"]))}
                r = submit(farm, scene, **form, **extra)
                assert r.status_code == 201, r.text
                job = r.json()["id"]
                status = wait_for_job(farm, job, timeout=120, processes=[worker], expect="done")
                assert status["settings"]["frame"] == time.get("frame")
                image = farm_image(farm, job, tmp_path)
                assert np.array_equal(image.view(np.uint32), want.view(np.uint32)), \
                    f"{form['integrator']} {time}: {np.count_nonzero(image != want)} values differ"
            fields = [f.decode() for key in farm_redis_keys(farm) for f in key]
            tag = "translated:" + format_tag()
            assert tag in fields and any(f.startswith(tag + ".t") for f in fields), fields
        finally:
            worker.stop()
        for bad in ("0.5,-0.5", "1", "a,b"):
            r = submit(farm, scene, spp=1, shutter=bad)
            assert r.status_code == 422 and "shutter" in r.text, (bad, r.text)
