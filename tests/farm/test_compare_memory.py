"""POST /compare holds the API's memory bounded: the comparison runs in a child process
with a memory limit, and an image over the pixel limit is refused from its header (413).
Real uvicorn API process and redis-server; the API's peak resident memory (VmHWM) is read
from /proc before and after.

Before the fix, two compressible 1024² renders (about 60 KB each) raised the API's peak by
about 700 MB (700 bytes per pixel; two 2048² took it to 3.1 GB)."""
from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np
import pytest

from conftest import start_api
from tessera_base import images

MiB = 1 << 20
SIDE = 1024
# What the API may gain across a comparison of SIDE² images: its own upload buffering and
# allocator noise. Decoding and comparing them takes ~700 bytes a pixel (700 MiB): a
# comparison in the API's own process raises its peak by 5x this at least.
API_GROWTH_MIB = 120


def _render(path: Path, mean: float, width: int = SIDE, height: int = SIDE) -> Path:
    """A constant render of `mean` with per-sample variance 1 at 16 spp (the kind `tessera
    render` writes); constant planes compress to a few KB, like the issue's 219 KB files."""
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = mean
    images.write_exr(path, rgba, metadata={images.VARIANCE_ATTRIBUTE: images.VARIANCE_PER_SAMPLE,
                                           "tessera:integrator": "path"},
                     aovs={"variance": np.ones((height, width, 3), np.float32),
                           "spp": np.full((height, width), 16, np.float32)})
    return path


def _peak_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("api"),
                           compare_max_pixels=str(SIDE * SIDE))
    with httpx.Client(base_url=base, timeout=120) as client:
        client.api = proc
        yield client
    proc.stop()


@pytest.fixture(scope="module")
def exrs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("exrs")
    return {"reference": _render(tmp / "reference.exr", 1.0),
            # The same image again: no pixel differs; any comparison says "same".
            "same": _render(tmp / "same.exr", 1.0),
            # 0.5 above: t = 0.5 / sqrt(2/16) = 1.4 per pixel, ~1400 sigma over the image.
            "shifted": _render(tmp / "shifted.exr", 1.5),
            "too_wide": _render(tmp / "too_wide.exr", 1.0, width=SIDE + 1)}


def _post(api, test: Path, reference: Path) -> httpx.Response:
    return api.post("/compare", files={"test": ("test.exr", test.read_bytes()),
                                       "reference": ("reference.exr", reference.read_bytes())},
                    data={"flip": "false"})


def test_a_large_comparison_leaves_the_api_small_and_keeps_its_verdicts(api, exrs):
    assert exrs["reference"].stat().st_size < 1 * MiB  # a small upload, a large image
    before = _peak_mib(api.api.pid)
    same = _post(api, exrs["same"], exrs["reference"])
    differs = _post(api, exrs["shifted"], exrs["reference"])
    after = _peak_mib(api.api.pid)
    assert same.status_code == 200 and differs.status_code == 200, (same.text, differs.text)
    assert same.json()["verdict"] == "same" and same.json()["width"] == SIDE
    assert differs.json()["verdict"] == "differs"
    assert after - before < API_GROWTH_MIB, (before, after)


def test_an_image_over_the_pixel_limit_is_refused_before_decoding(api, exrs):
    before = _peak_mib(api.api.pid)
    r = _post(api, exrs["too_wide"], exrs["reference"])
    assert r.status_code == 413, r.text
    detail = r.json()["detail"]
    assert f"{SIDE + 1}x{SIDE}" in detail and "TESSERA_COMPARE_MAX_PIXELS" in detail
    assert str(SIDE * SIDE) in detail
    # One pixel fewer is compared (the limit is inclusive).
    assert _post(api, exrs["same"], exrs["reference"]).status_code == 200
    assert _peak_mib(api.api.pid) - before < API_GROWTH_MIB


def test_a_comparison_past_its_memory_limit_is_413(tmp_path):
    """Two 2048² renders need about 3.2 GB; in a child limited to 1.5 GiB of address space
    (enough to start: 768 MiB is) the comparison is refused with 413 naming the setting."""
    from tessera_service.compare_process import CompareRefused, compare_in_child

    a, b = _render(tmp_path / "a.exr", 1.0, 2048, 2048), _render(tmp_path / "b.exr", 1.0, 2048, 2048)
    with pytest.raises(CompareRefused) as refused:
        compare_in_child(a, b, alpha=0.01, method="bh", flip=False, max_pixels=1 << 24,
                         memory_bytes=1536 * MiB, timeout=120)
    assert refused.value.status == 413 and "TESSERA_COMPARE_MEMORY_BYTES" in str(refused.value)
    # Control: the same pair within 6 GiB is compared (the refusal was the limit's).
    report = compare_in_child(a, b, alpha=0.01, method="bh", flip=False, max_pixels=1 << 24,
                              memory_bytes=6144 * MiB, timeout=120)
    assert report["verdict"] == "same" and report["width"] == 2048
