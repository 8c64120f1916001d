"""tessera.Client against a real farm (redis-server, the API under uvicorn, a worker
process; tests/conftest.py): submit, follow the events until done, download, and the image
equals tessera.render's bit for bit; cancel. Everything synchronises on the farm's events
and states, never on time."""
from __future__ import annotations

import numpy as np
import pytest

import tessera
from conftest import CORNELL, start_api, start_worker

pytestmark = pytest.mark.slow  # a whole farm: API and worker start-up

JOB = dict(spp=8, integrator="bdpt", res=(24, 16), seed=3, tile_size=8)


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("farm")
    api, url = start_api(redis_server, logs)
    worker = start_worker(redis_server, "api-client-worker", logs)
    try:
        with tessera.Client(url) as client:
            yield client
    finally:
        worker.stop()
        api.stop()


def test_submit_events_download_equals_a_local_render(farm, tmp_path):
    """bdpt splats across tiles: the farm merges the splats of six tiles, the local render
    has them in one buffer, and the two images are equal bit for bit. Negative control:
    the local render with another seed is not (the equality can fail)."""
    job = farm.submit(CORNELL, **JOB)
    assert job.state == "queued" and job.tiles_total == 6
    events = list(farm.events(job.id))
    assert events[-1].type == "state" and events[-1].state == "done", events[-1]
    assert max(e.tiles_done or 0 for e in events if e.type == "tile") == 6
    status = farm.status(job.id)
    assert status.state == "done" and status.tiles_done == 6 and status.error is None
    image = farm.download(job.id, tmp_path / "farm.exr")
    assert (tmp_path / "farm.exr").stat().st_size > 0
    local = tessera.render(CORNELL, **JOB)
    assert np.array_equal(image.rgb, local.rgb)
    assert image.header()["tessera:integrator"] == "bdpt" and image.header()["tessera:seed"] == "3"
    other = tessera.render(CORNELL, **dict(JOB, seed=4))
    assert not np.array_equal(image.rgb, other.rgb)


def test_cancel(farm):
    """A cancelled job ends its event stream with the cancelled state, and its image is
    refused (409) rather than half-rendered."""
    job = farm.submit(CORNELL, spp=4096, res=(64, 64), tile_size=8, integrator="path")
    cancelled = farm.cancel(job.id)
    assert cancelled.state == "cancelled"
    events = list(farm.events(job.id))
    assert events[-1].type == "state" and events[-1].state == "cancelled"
    assert farm.wait(job.id).state == "cancelled"
    with pytest.raises(tessera.FarmError) as info:
        farm.download(job.id)
    assert info.value.status_code == 409


def test_errors_are_the_servers_words(farm, tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\nthis is not USD\n")
    with pytest.raises(tessera.FarmError) as info:
        farm.submit(bad, spp=1)
    assert info.value.status_code == 422 and "cannot be rendered" in str(info.value)
    with pytest.raises(tessera.FarmError) as info:
        farm.status("0" * 32)
    assert info.value.status_code == 404
    with tessera.Client("http://127.0.0.1:9") as nowhere:
        with pytest.raises(tessera.FarmError, match="cannot talk"):
            nowhere.status("0" * 32)
