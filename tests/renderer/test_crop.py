"""A crop renders only the tiles that meet it, cut to it (protocol.job_tiles), and its
pixels equal the full render's region bit for bit: for path (tile passes), sppm and
radiosity (a scene-wide pass before the tiles), and for bdpt and light, whose crop pixels
gather light paths started from every pixel, so they still trace the whole frame.
The time this saves is measured in benchmarks/crop.py (docs/benchmarks/crop.md)."""
from __future__ import annotations

import numpy as np
import pytest

import tessera
from conftest import CORNELL
from tessera_base import integrators
from tessera_base.protocol import RenderSettings, job_tiles

RES = (64, 48)
CROP = (20, 12, 52, 44)  # not on the 16 px tile grid: edge tiles are cut
X0, Y0, X1, Y1 = CROP


def test_job_tiles_are_the_grid_tiles_meeting_the_crop_cut_to_it():
    s = RenderSettings(width=64, height=48, tile_size=16, crop=CROP, integrator="path")
    # Grid columns [0,16) [16,32) [32,48) [48,64), rows [0,16) [16,32) [32,48); index = row * 4 + col.
    expected = [(1, 20, 12, 12, 4), (2, 32, 12, 16, 4), (3, 48, 12, 4, 4),
                (5, 20, 16, 12, 16), (6, 32, 16, 16, 16), (7, 48, 16, 4, 16),
                (9, 20, 32, 12, 12), (10, 32, 32, 16, 12), (11, 48, 32, 4, 12)]
    assert [(t.index, t.x0, t.y0, t.width, t.height) for t in job_tiles(s)] == expected
    assert sum(t.width * t.height for t in job_tiles(s)) == (X1 - X0) * (Y1 - Y0)
    assert len(job_tiles(s.model_copy(update={"crop": None}))) == 12
    # Splatting integrators render the whole grid: a crop pixel gathers every pixel's light paths.
    for name in ("light", "bdpt"):
        assert integrators.splats(name)
        assert len(job_tiles(s.model_copy(update={"integrator": name}))) == 12


@pytest.fixture(scope="module")
def renders():
    out = {}
    for name in ("path", "bdpt", "light", "sppm", "radiosity"):
        common = dict(spp=4, res=RES, integrator=name, tile_size=16, seed=5)
        out[name] = tessera.render(CORNELL, **common), tessera.render(CORNELL, crop=CROP, **common)
    return out


@pytest.mark.parametrize("name", ["path", "bdpt", "light", "sppm", "radiosity"])
def test_crop_pixels_equal_the_full_render_bit_for_bit(renders, name):
    full, crop = renders[name]
    region = (slice(Y0, Y1), slice(X0, X1))
    assert np.array_equal(crop.rgba[region].view(np.uint32), full.rgba[region].view(np.uint32))
    assert float(crop.rgba[region][..., :3].mean()) > 0.01  # lit pixels, not two empty frames
    for layer in set(full.layers) | set(crop.layers):  # the noise estimate, where there is one
        assert np.array_equal(crop.layers[layer][region].view(np.uint32),
                              full.layers[layer][region].view(np.uint32)), layer
    # The check can fail: the next pixel column over differs from the region's.
    shifted = full.rgba[Y0:Y1, X0 + 1:X1 + 1]
    assert not np.array_equal(crop.rgba[region].view(np.uint32), shifted.view(np.uint32))


@pytest.mark.parametrize("name", ["path", "sppm", "radiosity"])
def test_crop_renders_only_its_pixels(renders, name):
    full, crop = renders[name]
    area, full_area = (X1 - X0) * (Y1 - Y0), RES[0] * RES[1]
    assert crop.metadata["samples"] == area * 4 and full.metadata["samples"] == full_area * 4
    outside = np.ones(crop.rgba.shape[:2], bool)
    outside[Y0:Y1, X0:X1] = False
    assert not crop.rgba[outside].any()  # never rendered


@pytest.mark.parametrize("name", ["bdpt", "light"])
def test_a_splatting_crop_traces_every_pixels_light_paths(renders, name):
    full, crop = renders[name]
    assert crop.metadata["samples"] == full.metadata["samples"] == RES[0] * RES[1] * 4
