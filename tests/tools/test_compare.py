"""`tessera compare`: renders that agree within noise compare equal, renders of a changed
scene (albedo 5 % off, light moved 10 mm) or with a NaN pixel compare different, usage
errors exit 2; plus the statistics on synthetic Gaussian images with known answers, and
POST /compare through a real uvicorn process."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

from conftest import CORNELL, start_api
from tessera_tools import compare
from tessera_base import images
from tessera_cli.cli import main

RES, SPP = "64x64", 32
WHITE = "(0.725, 0.71, 0.68)"
LIGHT = "(343, 548.7, 227), (343, 548.7, 332), (213, 548.7, 332), (213, 548.7, 227)"


def _render(scene: Path, out: Path, seed: int, *extra: str) -> Path:
    assert main(["render", str(scene), "-o", str(out), "--spp", str(SPP), "--res", RES,
                 "--seed", str(seed), "--threads", "2", "-q", *extra]) == 0
    return out


def _variant(tmp: Path, name: str, old: str, new: str) -> Path:
    text = CORNELL.read_text()
    assert old in text
    path = tmp / f"{name}.usda"
    path.write_text(text.replace(old, new))
    return path


@pytest.fixture(scope="module")
def renders(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("compare")
    brighter = "(%.6g, %.6g, %.6g)" % tuple(1.05 * v for v in (0.725, 0.71, 0.68))
    moved = LIGHT.replace("343", "353").replace("213", "223")  # 10 mm along x (box: 556 mm)
    return {
        "reference": _render(CORNELL, tmp / "reference.exr", 0),
        "seed1": _render(CORNELL, tmp / "seed1.exr", 1),
        "albedo": _render(_variant(tmp, "albedo", WHITE, brighter), tmp / "albedo.exr", 2),
        "light": _render(_variant(tmp, "light", LIGHT, moved), tmp / "light.exr", 3),
        "small": _render(CORNELL, tmp / "small.exr", 4, "--res", "32x32"),
    }


def _compare(tmp_path: Path, test: Path, reference: Path, *extra: str) -> tuple[int, dict]:
    report = tmp_path / "report.json"
    heat = tmp_path / "heat.png"
    rc = main(["compare", str(test), str(reference), "--report", str(report), "--heatmap", str(heat),
               *extra])
    assert heat.is_file() and report.is_file()
    return rc, json.loads(report.read_text())


def test_render_writes_variance_and_spp_channels(renders):
    image = images.read_render(renders["reference"])
    assert image.variance is not None and image.variance.shape == (64, 64, 3)
    assert (image.spp == SPP).all()
    assert (image.variance >= 0).all() and (image.variance > 0).mean() > 0.5
    # The renderer's own variance for the same pixels (the EXR stores it unchanged).
    from tessera_renderer import load_scene
    _, var = load_scene(CORNELL).render_tile(0, 0, 16, 16, width=64, height=64, spp=SPP, seed=0,
                                             threads=2, return_variance=True)
    np.testing.assert_array_equal(image.variance[:16, :16], var)
    # RGBA readers see RGBA only.
    assert images.read_exr(renders["reference"]).shape == (64, 64, 4)


def test_two_seeds_compare_the_same(renders, tmp_path):
    rc, report = _compare(tmp_path, renders["seed1"], renders["reference"])
    assert rc == 0, report
    assert report["verdict"] == "same" and report["reasons"] == []
    assert report["test_spp"] == SPP and report["nonfinite_pixels"] == 0
    assert [s["block"] for s in report["scales"]] == [1, 4, 16, 0]
    assert report["scales"][0]["tests"] > 3 * 64 * 64 * 0.9
    assert 0 < report["flip"] < 0.2 and report["rmse"] > 0 and report["relmse"] > 0


def test_identical_files_compare_the_same(renders, tmp_path):
    rc, report = _compare(tmp_path, renders["reference"], renders["reference"])
    assert rc == 0 and report["rmse"] == 0 and report["flip"] == 0


@pytest.mark.parametrize("variant", ["albedo", "light"])
@pytest.mark.parametrize("method", ["bh", "bonferroni"])
def test_a_changed_scene_compares_different(renders, tmp_path, variant, method):
    rc, report = _compare(tmp_path, renders[variant], renders["reference"], "--method", method)
    assert rc == 1, report
    assert report["verdict"] == "differs" and report["reasons"]
    assert report["first_difference"] is not None or any(s["block"] != 1 and s["significant"]
                                                         for s in report["scales"])


def _tessera_meta(image: images.RenderImage) -> dict[str, str]:
    return {k: v for k, v in image.metadata.items() if k.startswith("tessera:")}


def test_a_nan_pixel_compares_different(renders, tmp_path):
    image = images.read_render(renders["seed1"])
    image.rgba[10, 20, 1] = np.nan
    bad = tmp_path / "nan.exr"
    images.write_exr(bad, image.rgba, _tessera_meta(image), aovs={"variance": image.variance, "spp": image.spp})
    rc, report = _compare(tmp_path, bad, renders["reference"])
    assert rc == 1
    assert report["nonfinite_pixels"] == 1 and report["first_difference"] == [20, 10]
    assert "NaN/Inf" in report["reasons"][0]
    # An infinite variance is caught the same way.
    image = images.read_render(renders["seed1"])
    image.variance[3, 4, 0] = np.inf
    images.write_exr(bad, image.rgba, _tessera_meta(image), aovs={"variance": image.variance, "spp": image.spp})
    rc, report = _compare(tmp_path, renders["reference"], bad)
    assert rc == 1 and report["nonfinite_pixels"] == 1


def test_usage_errors_exit_2(renders, tmp_path, capsys):
    def run(*args: str) -> str:
        assert main(["compare", *args, "--heatmap", str(tmp_path / "h.png")]) == 2
        return capsys.readouterr().err

    assert "no such file" in run(str(tmp_path / "missing.exr"), str(renders["reference"]))
    assert "TEST is 32x32 but REFERENCE is 64x64" in run(str(renders["small"]), str(renders["reference"]))
    plain = tmp_path / "plain.exr"
    images.write_exr(plain, images.read_exr(renders["reference"]))
    assert "has no variance channels" in run(str(plain), str(renders["reference"]))
    garbage = tmp_path / "garbage.exr"
    garbage.write_bytes(b"not an image at all")
    assert "REFERENCE" in run(str(renders["reference"]), str(garbage))
    assert "alpha" in run(str(renders["reference"]), str(renders["seed1"]), "--alpha", "1.5")
    assert not (tmp_path / "h.png").exists()


def test_the_installed_command_exits_with_the_verdict(renders, tmp_path):
    """Through the real console script (exit codes as a CI job sees them)."""
    tessera = Path(sys.executable).with_name("tessera")
    plain = tmp_path / "plain.exr"
    images.write_exr(plain, images.read_exr(renders["reference"]))
    for args, code in (([renders["seed1"], renders["reference"]], 0),
                       ([renders["albedo"], renders["reference"]], 1),
                       ([plain, renders["reference"]], 2)):
        r = subprocess.run([str(tessera), "compare", *map(str, args), "--no-flip",
                            "--heatmap", str(tmp_path / "h.png")], capture_output=True, text=True)
        assert r.returncode == code, (args, r.stdout, r.stderr)
    assert "has no variance channels" in r.stderr


# ------------------------------------------------------------------ statistics, synthetic
def _gaussian(rng, mean: np.ndarray, sigma: float, n: int) -> images.RenderImage:
    """A render whose pixels are means of n Gaussian samples, with their sample variance."""
    h, w, _ = mean.shape
    samples = rng.normal(mean[None], sigma, size=(n, h, w, 3))
    rgba = np.concatenate([samples.mean(axis=0), np.ones((h, w, 1))], axis=2).astype(np.float32)
    return images.RenderImage(rgba, samples.var(axis=0, ddof=1).astype(np.float32),
                              np.full((h, w), n, np.float32), variance_kind=images.VARIANCE_PER_SAMPLE)


def test_false_alarm_rate_is_at_most_alpha_on_gaussian_noise():
    """200 comparisons of independent renders of one image at alpha 0.05: the number of
    'differs' is Binomial(200, <= 0.05); 22 or more would happen with probability < 0.2 %."""
    rng = np.random.default_rng(1)
    mean = rng.uniform(0.1, 2.0, size=(24, 24, 3))
    alarms = sum(compare.compare_images(_gaussian(rng, mean, 0.5, 8), _gaussian(rng, mean, 0.5, 16),
                                        alpha=0.05, flip=False).report.differs for _ in range(200))
    assert alarms < 22, alarms
    # Not vacuous: the same at alpha 0.5 raises alarms.
    alarms = sum(compare.compare_images(_gaussian(rng, mean, 0.5, 8), _gaussian(rng, mean, 0.5, 16),
                                        alpha=0.5, flip=False).report.differs for _ in range(40))
    assert alarms >= 5, alarms


def test_small_shifts_are_found_by_the_block_tests():
    """A shift of every pixel by 0.2 standard errors of the difference (no single pixel
    significant) is found by the whole-image test; 3 standard errors in one 4x4 patch by
    the 4x4 test."""
    rng = np.random.default_rng(2)
    mean = np.full((48, 48, 3), 1.0)
    sigma, n = 1.0, 16
    se = sigma * np.sqrt(2 / n)
    base = _gaussian(rng, mean, sigma, n)
    report = compare.compare_images(_gaussian(rng, mean + 0.2 * se, sigma, n), base, flip=False).report
    assert report.differs and report.scales[0].significant == 0 and report.scales[3].significant
    patch = mean.copy()
    patch[8:12, 8:12] += 3 * se
    report = compare.compare_images(_gaussian(rng, patch, sigma, n), base, flip=False).report
    assert report.differs and report.scales[1].significant


def test_zero_variance_pixels_must_agree_to_rounding():
    rgba = np.ones((4, 4, 4), np.float32)
    zero = np.zeros((4, 4, 3), np.float32)
    spp = np.full((4, 4), 4, np.float32)
    ref = images.RenderImage(rgba, zero, spp, variance_kind=images.VARIANCE_PER_SAMPLE)
    assert not compare.compare_images(images.RenderImage(rgba.copy(), zero, spp, variance_kind="per-sample"),
                                      ref).report.differs
    nudged = rgba.copy()
    nudged[1, 2, 0] += 5e-6                      # below ATOL + RTOL * 1 = 1.1e-5
    assert not compare.compare_images(images.RenderImage(nudged, zero, spp, variance_kind="per-sample"), ref).report.differs
    nudged[1, 2, 0] += 1e-3
    report = compare.compare_images(images.RenderImage(nudged, zero, spp, variance_kind="per-sample"), ref).report
    assert report.differs and report.exact_mismatch_pixels == 1 and report.first_difference == (2, 1)


def test_benjamini_hochberg_and_bonferroni():
    p = np.array([0.001, 0.008, 0.039, 0.041, 0.042, 0.06, 0.074, 0.205, 0.212, 0.216])
    # BH at 0.05: the largest k with p_(k) <= 0.05 k / 10 is k = 2.
    assert compare._reject(p, 0.05, "bh").tolist() == [True, True] + [False] * 8
    assert compare._reject(p, 0.05, "bonferroni").tolist() == [True] + [False] * 9
    assert compare._reject(np.full(5, 0.04), 0.05, "bh").all()       # BH: all at once
    assert not compare._reject(np.full(5, 0.04), 0.05, "bonferroni").any()


# ------------------------------------------------------------------ HTTP
@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("api"), max_upload_bytes=1 << 20)
    with httpx.Client(base_url=base, timeout=60) as client:
        yield client
    proc.stop()


def _post(api, test: Path | bytes, reference: Path | bytes, **form) -> httpx.Response:
    def part(name, x):
        return (name, x if isinstance(x, bytes) else x.read_bytes())
    return api.post("/compare", files={"test": part("test.exr", test), "reference": part("ref.exr", reference)},
                    data={k: str(v) for k, v in form.items()})


def test_endpoint_returns_the_report(api, renders):
    r = _post(api, renders["seed1"], renders["reference"])
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["verdict"] == "same" and body["width"] == 64 and body["flip"] is not None
    r = _post(api, renders["albedo"], renders["reference"], method="bonferroni", flip="false")
    assert r.status_code == 200, r.text
    assert r.json()["verdict"] == "differs" and r.json()["flip"] is None
    # The same report as the CLI's.
    expected = compare.compare_files(renders["albedo"], renders["reference"], method="bonferroni",
                                     flip=False).report
    assert compare.CompareReport(**r.json()) == expected
    spec = api.get("/openapi.json").json()
    assert spec["paths"]["/compare"]["post"]["responses"]["200"]["content"]["application/json"]


def test_endpoint_refuses_what_cannot_be_compared(api, renders):
    r = _post(api, renders["small"], renders["reference"])
    assert r.status_code == 422 and "is 32x32 but" in r.json()["detail"]
    r = _post(api, b"garbage", renders["reference"])
    assert r.status_code == 422 and "test.exr" in r.json()["detail"]
    assert "/tmp" not in r.json()["detail"]
    r = _post(api, renders["seed1"], renders["reference"], alpha="0")
    assert r.status_code == 422
    r = _post(api, b"x" * ((1 << 20) + 1), renders["reference"])
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    r = api.post("/compare", files={"test": ("t.exr", b"x")})
    assert r.status_code == 422


def test_no_variance_renders_once_and_compare_refuses_it(tmp_path, capsys):
    """`--no-variance` writes no variance layer (light and bdpt keep no batches),
    and compare says it cannot judge such an image instead of guessing."""
    a = _render(CORNELL, tmp_path / "a.exr", 0, "--integrator", "bdpt", "--no-variance")
    b = _render(CORNELL, tmp_path / "b.exr", 1, "--integrator", "bdpt")
    assert images.read_render(a).variance is None and images.read_render(b).variance is not None
    capsys.readouterr()
    assert main(["compare", str(a), str(b), "--heatmap", str(tmp_path / "h.png")]) == 2
    assert "variance" in capsys.readouterr().err
