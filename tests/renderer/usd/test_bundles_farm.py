"""Malicious bundles sent to the real farm (redis-server, uvicorn, a worker process) are
refused with a 4xx naming the offending path, and the farm then renders a valid zip
bundle (relative references and a texture) to completion."""
from __future__ import annotations

import textwrap
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from conftest import start_api, start_worker, submit, wait_for_job
from test_bundles import MESH, layer, texture_material, write_zip


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("bundle-farm")
    api_proc, base = start_api(redis_server, logs)
    worker = start_worker(redis_server, "w-bundles", logs)
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes = [api_proc, worker]
        yield client
    worker.stop()
    api_proc.stop()


def test_malicious_bundles_get_a_4xx_and_a_valid_bundle_still_renders(farm, tmp_path):
    secret = tmp_path / "secret.usda"
    secret.write_text(layer('def "Leaked" {}'))
    bad = {
        "escaping reference": (write_zip(tmp_path / "escape.zip", [
            ("scene.usda", layer('def "R" (references = @../secret.usda@) {}\n' + MESH))]), "../secret.usda"),
        "absolute texture": (write_zip(tmp_path / "abs.zip", [
            ("scene.usda", layer(texture_material("/etc/passwd")))]), "/etc/passwd"),
        "zip bomb": (write_zip(tmp_path / "bomb.zip", [
            ("scene.usda", layer(MESH)), ("zeros.bin", bytes(30 << 20))]), "zeros.bin"),
        "zip slip": (write_zip(tmp_path / "slip.zip", [
            ("scene.usda", layer(MESH)), ("../../evil.usda", layer())]), "../../evil.usda"),
        "loose layer reaching out": ((tmp_path / "loose.usda"), str(secret)),
    }
    (tmp_path / "loose.usda").write_text(layer(f'def "R" (references = @{secret}@) {{}}\n' + MESH))
    for label, (path, offending) in bad.items():
        r = submit(farm, path, width=16, height=16, spp=1)
        assert 400 <= r.status_code < 500, (label, r.status_code, r.text)
        assert offending in r.json()["detail"], (label, r.json())

    # A valid bundle: root layer + a referenced layer in a sub-folder + a texture.
    sub = layer(textwrap.dedent("""\
        def Xform "Light" {
            double3 xformOp:translate = (0.25, 0.25, 3)
            uniform token[] xformOpOrder = ["xformOp:translate"]
            def SphereLight "L" {
                float inputs:radius = 0.5
                float inputs:intensity = 4
            }
        }
    """), 'defaultPrim = "Light"')
    from OpenImageIO import ImageBuf
    ImageBuf(np.full((4, 4, 3), 180, np.uint8)).write(str(tmp_path / "t.png"))
    good = write_zip(tmp_path / "good.zip", [
        ("scene.usda", layer('def "Lamp" (references = @./parts/light.usda@) {}\n'
                             + texture_material("textures/t.png"))),
        ("parts/light.usda", sub),
        ("textures/t.png", (tmp_path / "t.png").read_bytes())])
    r = submit(farm, good, width=16, height=16, spp=2, tile_size=8)
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    assert all(p.alive() for p in farm.processes)
    with zipfile.ZipFile(good) as zf:
        assert zf.namelist()[0] == "scene.usda"


def zip_scene(folder: Path, root_layer: str, out: Path) -> Path:
    """The whole scene folder as a zip bundle, its root layer first (the bundle rule)."""
    with zipfile.ZipFile(out, "w") as zf:
        zf.write(folder / root_layer, root_layer)
        for p in sorted(folder.rglob("*")):
            rel = str(p.relative_to(folder))
            if p.is_file() and rel != root_layer:
                zf.write(p, rel)
    return out


@pytest.mark.shared_scenes
def test_real_scenes_render_through_the_farm_as_zip_bundles(farm, tmp_path):
    from test_real_scenes import ROOTS, SCENES

    jobs = {}
    for k, (folder, rel, _, checks) in enumerate(ROOTS):
        bundle = zip_scene(SCENES / folder, rel, tmp_path / f"{k}-{folder}.zip")
        r = submit(farm, bundle, width=8, height=8, spp=1, tile_size=8, max_depth=2)
        assert r.status_code == 201, (folder, rel, r.text)
        jobs[(folder, rel)] = r.json()["id"]
    for key, job_id in jobs.items():
        status = wait_for_job(farm, job_id, timeout=120, processes=farm.processes)
        assert status["state"] == "done", (key, status)
