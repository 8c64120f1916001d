"""sppm on examples/caustic/caustic_mirror.usda, where the glass sphere's caustic is seen
only in a mirror (L S D S E): no bidirectional connection can reach those pixels (both ends
of the diffuse vertex are delta), so a high-sample `path` render is the reference, and
sppm must converge to it: its error keeps falling with the iterations (no plateau).

The reference is two independent path renders of REF_SPP samples (cached under the system
temp directory, keyed by the scene's bytes, since it takes a minute), so its own noise is
known: for a = ref_1, b = ref_2 and ref = (a + b) / 2, E[(x - ref)^2] = E[(x - true)^2] +
E[((a - b) / 2)^2], and the error of sppm is measured with that noise subtracted:
    relMSE(x) = mean over pixels and channels of ((x - ref)^2 - ((a - b) / 2)^2) / (ref^2 + 1e-2)
(the bench's relMSE, docs/benchmarks, less the reference's share).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import REPO
from tessera_base.protocol import RenderSettings, pass_range
from tessera_renderer import load_scene
from vcm_helpers import cached_halves

pytestmark = pytest.mark.slow

MIRROR = REPO / "examples" / "caustic" / "caustic_mirror.usda"
W = H = 32
MAX_DEPTH = 16
REF_SPP = 32768
ITERATIONS = 8  # 128 samples a pixel, 128 photon batches
PARAMS = {"photons": 50000}


def reference() -> tuple[np.ndarray, np.ndarray]:
    scene = load_scene(str(MIRROR))
    return cached_halves("mirror", scene, f"{W}x{H}:{REF_SPP}:{MAX_DEPTH}", lambda seed: scene.render_tile(
        0, 0, W, H, width=W, height=H, spp=REF_SPP, seed=seed, max_depth=MAX_DEPTH, threads=2,
        integrator="path")[..., :3])


def sppm_iterations(alpha: float = 2 / 3) -> list[np.ndarray]:
    """The sppm image after each iteration, as tessera.film averages passes."""
    scene = load_scene(str(MIRROR))
    params = {**PARAMS, "alpha": alpha}
    settings = RenderSettings(width=W, height=H, seed=9, max_depth=MAX_DEPTH, target_error=1e-9, min_spp=1,
                              max_spp=2 ** (ITERATIONS - 1), integrator="sppm")
    acc, total, out = None, 0, []
    for k in range(ITERATIONS):
        start, spp = pass_range(settings, k)
        product = scene.scene_pass("sppm", k, seed=9, max_depth=MAX_DEPTH, threads=2, integrator_params=params)
        img = scene.render_tile(0, 0, W, H, width=W, height=H, spp=spp, sample_start=start, seed=9,
                                max_depth=MAX_DEPTH, threads=2, integrator="sppm", integrator_params=params,
                                scene_product=product)[..., :3].astype(np.float64)
        acc = img * spp if acc is None else acc + img * spp
        total += spp
        out.append(acc / total)
    return out


def rel_mse(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ref = (a + b) / 2
    return float(np.mean(((x - ref) ** 2 - ((a - b) / 2) ** 2) / (ref * ref + 1e-2)))


def slope(x, y) -> float:
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(lx, ly, 1)[0])


@pytest.fixture(scope="module")
def ref():
    return reference()


@pytest.fixture(scope="module")
def images():
    return sppm_iterations()


def test_sppm_error_keeps_falling_with_iterations(ref, images):
    """relMSE after 2^k batches (k = 0..7), the reference's noise subtracted, keeps falling:
    every checkpoint from 8 batches on is below the one before, and the log-log slope over
    the last five is below -0.3 (Knaus-Zwicker: about -2/3 asymptotically). The sampling
    error of the subtracted noise term must be below a third of the last checkpoint, so the
    last points are resolved. Negative control: a plateau (the images after 32 batches
    repeated instead of the later ones) fails the same check."""
    a, b = ref
    ref_m = (a + b) / 2
    term = ((a - b) / 2) ** 2 / (ref_m * ref_m + 1e-2)
    term_se = float(term.std() / math.sqrt(term.size))
    J = [2 ** k for k in range(ITERATIONS)]
    errs = [rel_mse(x, a, b) for x in images]
    for j, e in zip(J, errs):
        print(f"sppm after {j:4d} batches: relMSE {e:.3e}")
    print(f"reference relMSE {float(term.mean()):.2e} +- {term_se:.1e} (subtracted)")

    def keeps_falling(e) -> bool:
        return all(later < earlier for earlier, later in zip(e[3:], e[4:])) and slope(J[3:], e[3:]) < -0.3

    print(f"slope over the last five: {slope(J[3:], errs[3:]):.2f}")
    assert term_se < errs[-1] / 3, (term_se, errs[-1])
    assert keeps_falling(errs), errs
    plateau = [rel_mse(images[min(k, 5)], a, b) for k in range(ITERATIONS)]
    assert not keeps_falling(plateau), "negative control"


def test_sppm_converges_to_the_reference_in_the_mirror(ref, images):
    """In the mirror (the upper three fifths of the image: the back wall, where the floor and
    its caustic are seen reflected, L S D S E and L S S D S E) the mean of sppm's last image
    agrees with the reference within 3 %, the reference's halves within 1 % of each other;
    so the check detects 4 %: sppm scaled by 4 % away from the reference must fail it."""
    a, b = ref
    rows = slice(0, 3 * H // 5)
    ref_m = ((a + b) / 2)[rows].mean()
    noise = abs(a[rows].mean() - b[rows].mean()) / 2 / ref_m
    ratio = images[-1][rows].mean() / ref_m
    print(f"mirror rows: sppm / reference {ratio:.4f}, reference halves +-{noise:.2%}")
    assert noise < 0.01
    assert abs(ratio - 1) < 0.03
    control = ratio * (1 + math.copysign(0.04, ratio - 1))
    assert abs(control - 1) >= 0.03, "negative control"
