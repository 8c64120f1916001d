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
from tessera import images, refs

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def farm_url(redis_server, tmp_path_factory):
    logs = tmp_path_factory.mktemp("farm")
    api, base = start_api(redis_server, logs)
    worker = start_worker(redis_server, "w-refs", logs)
    yield base
    worker.stop()
    api.stop()


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
    shared = ("tessera:spp", "tessera:seed", "tessera:integrator", "tessera:variance", "tessera:version")
    assert {k: meta[0][k] for k in shared} == {k: meta[1][k] for k in shared}
