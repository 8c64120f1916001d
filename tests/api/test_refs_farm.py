"""`tessera refs create --farm URL`: a reference rendered on a real farm (API + a worker on
a real redis-server) equals the one rendered locally, channel for channel and bit for bit,
for path and bdpt (batch-means variance), and the set it makes checks like a local one."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import CORNELL, start_api, start_worker
from tessera_base import images
from tessera import refs

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def farm_url(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("farm")
    api, base = start_api(redis_server, logs)
    worker = start_worker(redis_server, "w-refs", logs)
    yield base
    worker.stop()
    api.stop()


def png_size(path) -> tuple[int, int]:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return spec.width, spec.height


def create(folder, *args: str) -> None:
    r = subprocess.run([sys.executable, "-m", "tessera", "refs", "create", str(folder), str(CORNELL),
                        "--res", "24x16", "--spp", "32", "--seed", "7", *args],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("integrator", ["path", "bdpt"])
def test_farm_reference_equals_the_local_one(farm_url, tmp_path, integrator):
    create(tmp_path / "local", "--integrator", integrator)
    create(tmp_path / "farm", "--integrator", integrator, "--farm", farm_url)
    entry = json.loads((tmp_path / "farm" / refs.MANIFEST).read_text())["references"][0]
    assert entry["rendered_on"] == "farm" and entry["integrator"] == integrator
    local, farm = (images.read_exr_channels(tmp_path / side / "cornell.exr") for side in ("local", "farm"))
    assert set(local) == set(farm) == {"R", "G", "B", "A", "variance.R", "variance.G", "variance.B", "spp"}
    for name in local:
        assert np.array_equal(local[name].view(np.uint32), farm[name].view(np.uint32)), name
    meta = [images.read_render(tmp_path / side / "cornell.exr").metadata for side in ("local", "farm")]
    shared = ("tessera:spp", "tessera:seed", "tessera:integrator", "tessera:variance", "tessera:version",
              "tessera:reached_error")
    assert {k: meta[0][k] for k in shared} == {k: meta[1][k] for k in shared}


@pytest.mark.parametrize("integrator", ["path", "bdpt"])
def test_crop_job_field_writes_the_region_as_data_window(farm_url, tmp_path, integrator):
    """The job field `crop`: the farm queues only the tiles meeting the region (2 of the 6
    tiles of 8 px; bdpt all 6, for every pixel's light paths, with the region as their
    camera window), its EXR holds the region as its data window inside the full display
    window, with the pixels of the same job rendered whole, bit for bit, and its PNG is
    the region."""
    import httpx

    exrs = {}
    with httpx.Client(base_url=farm_url, timeout=60) as client:
        for name, extra in (("full", {}), ("crop", {"crop": "10,2,20,7"}), ("bad", {"crop": "4,2,40,14"})):
            with open(CORNELL, "rb") as f:
                r = client.post("/jobs", files={"file": ("cornell.usda", f)},
                                data={"width": "24", "height": "16", "spp": "8", "seed": "2", "tile_size": "8",
                                      "integrator": integrator, **extra})
            if name == "bad":
                assert r.status_code == 422 and "not a non-empty region" in r.text, r.text
                continue
            assert r.status_code == 201, r.text
            assert r.json()["tiles_total"] == {"full": 6, "crop": 2 if integrator == "path" else 6}[name]
            job = r.json()["id"]
            while (state := client.get(f"/jobs/{job}").json()["state"]) not in ("done", "failed", "cancelled"):
                import time
                time.sleep(0.1)
            assert state == "done"
            exrs[name] = tmp_path / f"{name}.exr"
            exrs[name].write_bytes(client.get(f"/jobs/{job}/image.exr").content)
            png = tmp_path / f"{name}.png"
            png.write_bytes(client.get(f"/jobs/{job}/preview.png").content)
            assert png_size(png) == {"full": (24, 16), "crop": (10, 5)}[name]
    head = subprocess.run(["exrheader", str(exrs["crop"])], capture_output=True, text=True).stdout
    assert "dataWindow (type box2i): (10 2) - (19 6)" in head
    assert "displayWindow (type box2i): (0 0) - (23 15)" in head
    full, crop = images.read_exr(exrs["full"]), images.read_exr(exrs["crop"])
    assert np.array_equal(crop.view(np.uint32), full[2:7, 10:20].view(np.uint32))
