"""The lane-group path kernel (`path`'s setting `lanes`, renderer/core/integrators/path_lanes.h)
on the Cornell box as exporters write it (UsdPreviewSurface turned Lambertian at load): every
lane width, tile split, sample-range split and thread count gives the scalar kernel's bits,
so a pixel depends only on (scene, pixel, sample index, seed) whichever kernel a worker runs.
The comparison can fail: a render of another seed differs in its bits."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import CORNELL
from tessera_renderer import load_scene

EXPORTED = CORNELL.with_name("cornell_exported.usda")
W, H, SPP = 24, 16, 9  # 9: not a multiple of a lane width, so lanes regenerate mid-pixel


@pytest.fixture(scope="module")
def scene():
    return load_scene(EXPORTED)


def render(scene, lanes, threads=1, tiles=((0, 0, W, H),), ranges=((0, SPP),), seed=5):
    img = np.zeros((H, W, 4), np.float32)
    for x0, y0, w, h in tiles:
        acc = np.zeros((h, w, 4), np.float64)
        for start, n in ranges:
            part = scene.render_tile(x0, y0, w, h, width=W, height=H, spp=n, sample_start=start, seed=seed,
                                     threads=threads, integrator="path", integrator_params={"lanes": lanes})
            acc += part.astype(np.float64) * n
        img[y0:y0 + h, x0:x0 + w] = (acc / SPP).astype(np.float32) if len(ranges) > 1 else part
    return img


def same_bits(a, b) -> bool:
    return np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_every_lane_width_tile_and_thread_count_gives_the_scalar_kernels_bits(scene):
    reference = render(scene, 0)
    assert reference[..., :3].mean() > 0.05  # a lit image
    quads = ((0, 0, 11, 7), (11, 0, 13, 7), (0, 7, 11, 9), (11, 7, 13, 9))
    for lanes in (8, 4, 1, -1):
        assert same_bits(render(scene, lanes), reference), lanes
        assert same_bits(render(scene, lanes, threads=2, tiles=quads), reference), lanes
    # Samples split over calls: compared with the scalar kernel split alike (the split's
    # own rounding of the mean is not the kernel's to keep).
    split = ((0, 4), (4, 5))
    assert same_bits(render(scene, 8, ranges=split), render(scene, 0, ranges=split))
    assert not same_bits(render(scene, 8, seed=6), reference)  # control: the check sees a change


def test_a_lane_width_it_has_not_is_refused(scene):
    with pytest.raises(ValueError, match="lanes must be 0"):
        render(scene, 3)
