"""`seed_offset`, the render setting added through its one declaration alone
(RenderSettings' field with settings_spec.Takes; docs/extending.md, "A new render
setting"): the API, the farm, the CLI's render and submit and the Python API all take it,
and a farm render with it equals the local render with it bit for bit."""
from __future__ import annotations

import httpx
import numpy as np
import pytest

from conftest import CORNELL, farm_image, start_api, start_worker, submit, wait_for_job
from tessera_base import images

pytestmark = pytest.mark.slow  # a real farm

FORM = dict(width=24, height=20, spp=2, seed=7, max_depth=8, tile_size=16)  # 2x2 uneven tiles
OFFSET = 5


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("seed-offset")
    api, base = start_api(redis_server, logs)
    worker = start_worker(redis_server, "w-seed", logs)
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes, client.base = [api, worker], base
        yield client
    worker.stop()
    api.stop()


def farm_render(farm, tmp_path, **form) -> np.ndarray:
    r = submit(farm, CORNELL, **form)
    assert r.status_code == 201, r.text
    wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    return farm_image(farm, r.json()["id"], tmp_path)


def local_render(**settings) -> np.ndarray:
    import tessera

    s = dict(FORM, **settings)
    return tessera.render(CORNELL, res=(s.pop("width"), s.pop("height")), variance=False, **s).rgba


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool((a.view(np.uint32) == b.view(np.uint32)).all())


def test_a_farm_render_with_a_seed_offset_equals_the_local_one_and_differs_without(farm, tmp_path):
    with_offset = farm_render(farm, tmp_path, **FORM, seed_offset=OFFSET)
    assert same_bits(with_offset, local_render(seed_offset=OFFSET))
    # The control: the offset changes the image (the comparison above can fail) ...
    without = farm_render(farm, tmp_path, **FORM)
    assert same_bits(without, local_render())
    assert not same_bits(with_offset, without)
    # ... and the offset is added to the seed, as its declaration says.
    assert same_bits(with_offset, local_render(seed=FORM["seed"] + OFFSET))


def test_the_cli_takes_it_for_render_and_submit(farm, tmp_path):
    from tessera_cli.cli import main

    options = ["--res", "24x20", "--spp", "2", "--seed", "7", "--max-depth", "8", "--tile", "16",
               "--seed-offset", str(OFFSET), "-q"]
    assert main(["render", str(CORNELL), "-o", str(tmp_path / "local.exr"), "--no-variance", *options]) == 0
    assert main(["submit", str(CORNELL), "--server", farm.base, "--wait", "-o", str(tmp_path / "farm.exr"),
                 *options]) == 0
    local, farmed = images.read_exr(tmp_path / "local.exr"), images.read_exr(tmp_path / "farm.exr")
    assert same_bits(local, farmed)
    assert same_bits(local, local_render(seed_offset=OFFSET))


@pytest.mark.parametrize("value", ["-1", str(2**32), "five"])
def test_the_api_refuses_an_offset_out_of_bounds_naming_it(farm, value):
    r = submit(farm, CORNELL, **FORM, seed_offset=value)
    assert r.status_code == 422, r.text
    assert [e["loc"] for e in r.json()["detail"]] == [["body", "seed_offset"]]
    assert submit(farm, CORNELL, **FORM, seed_offset="0").status_code == 201  # the control
