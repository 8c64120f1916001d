"""The job setting variants: the farm renders the stage with the job's variant selections,
bit for bit as a local render with them does, from a blob of its own; a malformed
selection, one the stage cannot make (naming the choices) and one whose layer is missing
from the upload are refused at submission: the pre-flight composes the stage with the
job's selections, so a layer only an unselected variant uses is information, not an
error."""
from __future__ import annotations

import numpy as np

from conftest import api_client, farm_image, start_worker, submit, wait_for_job
from tessera import local
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene
from test_farm_camera import SCENE as CAMERA_SCENE
from test_farm_subdivision import farm_redis_keys

# The camera test's scene with a variant set on the ball: its size.
SCENE = CAMERA_SCENE.replace('''def Sphere "Ball" {
    double radius = 0.7''', '''def Sphere "Ball" (
    variants = {string size = "small"}
    prepend variantSets = "size"
) {
    variantSet "size" = {
        "small" {
            double radius = 0.4
        }
        "big" {
            double radius = 1.2
        }
    }''')
FORM = {"spp": 4, "tile_size": 24, "integrator": "path"}


def test_farm_renders_the_jobs_variant_selection_as_a_local_render_does(redis_server, tmp_path):
    assert SCENE != CAMERA_SCENE
    scene = tmp_path / "ball_sizes.usda"
    scene.write_text(SCENE)
    settings = RenderSettings(width=48, height=48, **FORM)
    local_big = local.render_image(load_scene(scene, variants=[("/Ball", "size", "big")]), settings,
                                   progress=False, variance=False).rgba
    local_small = local.render_image(load_scene(scene), settings, progress=False, variance=False).rgba
    assert np.count_nonzero(np.any(local_big != local_small, axis=-1)) > 200  # the selection matters
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        worker = start_worker(farm.redis_url, "variants-0", farm.log_dir)
        try:
            r = submit(farm, scene, **FORM, variants="/Ball:size=big")
            assert r.status_code == 201, r.text
            status = wait_for_job(farm, r.json()["id"], timeout=120, processes=[worker], expect="done")
            assert status["settings"]["variants"] == ["/Ball:size=big"]
            image = farm_image(farm, r.json()["id"], tmp_path)
            assert np.array_equal(image.view(np.uint32), local_big.view(np.uint32))
            fields = [f.decode() for key in farm_redis_keys(farm) for f in key]
            assert any(f.startswith("translated:") and ".v" in f for f in fields), fields
        finally:
            worker.stop()
        # A selection the stage cannot make is refused at submission, naming the choices.
        r = submit(farm, scene, **FORM, variants="/Ball:size=huge")
        assert r.status_code == 422 and "has no variant 'huge' (choices: big, small)" in r.text, r.text
        r = submit(farm, scene, **FORM, variants="Ball:size")
        assert r.status_code == 422 and "must be /Prim/Path:set=value" in r.text, r.text


BIG_FROM_A_LAYER = ("""        "big" {
            double radius = 1.2""", """        "big" (references = @./big_ball.usda@) {
            double radius = 1.2""")


def test_preflight_checks_the_layers_the_jobs_selection_uses(redis_server, tmp_path):
    """The big ball's variant references a layer the upload lacks: with the stage's own
    selection (small) that is information and the job is accepted; selecting big is
    refused at once, naming the layer, and the refusal is remembered per selection (the
    default selection still passes afterwards)."""
    assert BIG_FROM_A_LAYER[0] in SCENE
    scene = tmp_path / "ball_layers.usda"
    scene.write_text(SCENE.replace(*BIG_FROM_A_LAYER))
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        for attempt in range(2):
            r = submit(farm, scene, **FORM, variants="/Ball:size=big")
            assert r.status_code == 422 and "big_ball.usda' is not in the bundle" in r.text, (attempt, r.text)
            r = submit(farm, scene, **FORM)
            assert r.status_code == 201, r.text
            warnings = r.json()["warnings"]
            assert any(w.startswith("information:") and "big_ball.usda" in w for w in warnings), warnings
