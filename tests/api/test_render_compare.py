"""tessera.render and tessera.compare (the public API, issue 19): a render is checked
against another integrator, never against itself. Path tracing and light tracing share no
code past the scene, and light tracing's image is all splats, so agreement also shows
that the splats come out of tessera.render normalised."""
from __future__ import annotations

import numpy as np
import pytest

import tessera
from conftest import CORNELL
from tessera_tools.compare import CompareError

RES = (32, 32)
SPP = 64


@pytest.fixture(scope="module")
def path_and_light():
    path = tessera.render(CORNELL, spp=SPP, integrator="path", res=RES, seed=1)
    light = tessera.render(CORNELL, spp=SPP, integrator="light", res=RES, seed=2)
    return path, light


def _brighter(image: tessera.Image, factor: float) -> tessera.Image:
    """The same render with every pixel `factor` times brighter (its noise scaled alike)."""
    layers = dict(image.layers, variance=image.layers["variance"] * np.float32(factor * factor))
    return tessera.Image(image.rgba * np.float32(factor), layers, dict(image.metadata))


def test_path_and_light_tracing_agree_and_a_one_percent_error_is_found(path_and_light):
    """The two integrators' images agree within their noise (compare's false-alarm rate
    is alpha = 0.01), and their whole-image means within 2 %. Smallest error detected: 1 %
    of brightness; negative control: the light image made 1 % brighter must differ (the
    whole-image scale has a noise of about 0.2 % at this size and spp)."""
    path, light = path_and_light
    report = tessera.compare(path, light)
    assert not report.differs, report.summary()
    mean_path, mean_light = np.mean(report.mean_test), np.mean(report.mean_reference)
    assert abs(mean_light / mean_path - 1) < 0.02
    assert tessera.compare(path, _brighter(light, 1.01)).differs
    assert tessera.compare(path, _brighter(light, 1 / 1.01)).differs


def test_render_returns_layers_and_metadata(path_and_light):
    path, light = path_and_light
    for image, name, kind in ((path, "path", "per-sample"), (light, "light", "batch-means:8")):
        assert image.rgba.shape == (RES[1], RES[0], 4) and image.rgba.dtype == np.float32
        assert image.layers["variance"].shape == (RES[1], RES[0], 3)
        assert (image.layers["spp"] == SPP).all()
        assert image.metadata["tessera:integrator"] == name and image.metadata["integrator"] == name
        assert image.metadata["tessera:variance"] == kind
        assert image.metadata["tessera:spp"] == str(SPP) and image.metadata["samples"] == SPP * RES[0] * RES[1]
    albedo = tessera.render(CORNELL, spp=4, res=(8, 8), aovs=["albedo"])
    assert albedo.layers["albedo"].shape == (8, 8, 3) and "albedo" not in path.layers


def test_an_image_written_and_read_back_compares_as_the_file(path_and_light, tmp_path):
    """tessera.Image.write writes what `tessera compare` reads: the file and the object
    give the same report, and the file's pixels are the object's bit for bit."""
    path, light = path_and_light
    file = light.write(tmp_path / "light.exr")
    back = tessera.Image.read(file)
    assert np.array_equal(back.rgba, light.rgba)
    assert np.array_equal(back.layers["variance"], light.layers["variance"])
    assert back.header() == light.header()
    assert tessera.compare(path, file) == tessera.compare(path, light)


def test_compare_refuses_an_image_without_noise_estimate(path_and_light):
    path, _ = path_and_light
    bare = tessera.Image(path.rgba, {}, dict(path.metadata))
    with pytest.raises(CompareError, match="variance"):
        tessera.compare(path, bare)


def test_render_reports_bad_settings_in_the_users_terms():
    with pytest.raises(ValueError, match="spp"):
        tessera.render(CORNELL, spp=0, res=(8, 8))
    with pytest.raises(ValueError, match="integrator"):
        tessera.render(CORNELL, spp=1, res=(8, 8), integrator="no-such-integrator")
