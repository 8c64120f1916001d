"""sppm on the glass-ball caustic of tests/test_caustic.py (a smooth glass ball over a
Lambertian floor under a small sphere light; its floor regions are known from the
geometry): sppm agrees with bdpt and with light tracing per region (caustic disk, shadow
ring, open floor) within noise, and the comparisons are powerful enough to see a 2 %
difference in every region.

Statistics as in test_caustic.py: per-seed region means, Welch's t per region and pair, the
limit the Student-t quantile for a family-wise false-alarm rate of 1e-3 (Bonferroni over
the comparisons), and each comparison's power (the smallest relative difference it would
detect) asserted, with a negative control: sppm scaled by the required difference fails.

sppm's noise and bias: 16 seeds, each 5 iterations (16 photon batches of 1.5e5 paths, 16
samples a pixel) from a radius of 0.02 down to 0.013 (the caustic disk's radius is ~0.2,
so the kernel blurs only a thin band at its edge). The caustic's value is all photons (the
ball shadows the light), and their count sets the power. sppm aims half its photons at the
glass ball (its default `aim`, a projection map: photon_map.h); without that, the same
photons detected only 3.4 % in the caustic, since ~0.8 % of the light's photons reach the
ball. Every region must now detect 2 %.

Measured (sppm vs bdpt / vs light): caustic +0.02 % / +0.42 %, detects 1.56 % / 1.31 %;
shadow ring +0.24 % / -0.13 %, detects 1.8 %; open floor +0.02 % / -0.01 %, detects
0.1-0.3 %. About 2 minutes on a quiet 2-core machine.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import render_cache
import test_caustic as tc
from tessera_base.protocol import RenderSettings, pass_range

pytestmark = pytest.mark.slow

SPPM_SEEDS = 16
SPPM_PARAMS = {"photons": 150000, "radius": 0.02}
SPPM_ITERATIONS = 5
REQUIRED = {"caustic": 0.02, "shadow": 0.02, "lit": 0.02}


def render_sppm(scene, seed: int, iterations: int = SPPM_ITERATIONS, params=SPPM_PARAMS) -> list[np.ndarray]:
    """The image after each iteration, as the farm and tessera.local average passes."""
    settings = RenderSettings(width=tc.W, height=tc.H, seed=seed, max_depth=8, target_error=1e-9,
                              min_spp=1, max_spp=2 ** (iterations - 1), integrator="sppm")
    total, acc, out = 0, None, []
    for k in range(iterations):
        start, spp = pass_range(settings, k)

        def iteration() -> dict[str, np.ndarray]:
            product = scene.scene_pass("sppm", k, seed=seed, max_depth=8, threads=2, integrator_params=params)
            return {"img": scene.render_tile(0, 0, tc.W, tc.H, width=tc.W, height=tc.H, spp=spp, sample_start=start,
                                             seed=seed, max_depth=8, threads=2, integrator="sppm",
                                             integrator_params=params, scene_product=product)}

        # Cached across runs by scene, settings and core (tests/render_cache.py).
        img = render_cache.cached("sppm-caustic", scene, {"iteration": k, "start": start, "spp": spp, "seed": seed,
                                                          "params": params, "size": [tc.W, tc.H], "max_depth": 8},
                                  iteration)["img"][..., :3].astype(np.float64)
        acc = img * spp if acc is None else acc + img * spp
        total += spp
        out.append(acc / total)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    scene = tc.write_scene(tmp_path_factory.mktemp("sppm-caustic") / "caustic.usda")
    r = tc.floor_radius()
    # The renders test_caustic.py compares (the same scene, seeds and spp): made once.
    runs = {name: [tc.glass_region_means(scene, name, s) for s in range(tc.SEEDS[name])] for name in ("light", "bdpt")}
    runs["sppm"] = [tc.region_means(render_sppm(scene, 1000 + s)[-1], r) for s in range(SPPM_SEEDS)]
    return runs


def test_sppm_agrees_with_bdpt_and_light_per_region(runs):
    pairs = [("sppm", "bdpt"), ("sppm", "light")]
    comparisons = len(pairs) * len(tc.REGIONS)
    failures, weak, detectable = [], [], {}
    for a, b in pairs:
        for region in tc.REGIONS:
            xa = np.array([m[region] for m in runs[a]])
            xb = np.array([m[region] for m in runs[b]])
            t, df, se = tc.welch(xa, xb)
            limit = tc.student_t_quantile(1 - tc.FAMILY_ALPHA / (2 * comparisons), df)
            detectable[(b, region)] = d = limit * se / abs(np.mean(xb))
            print(f"{a} vs {b}, {region}: {np.mean(xa):.4f} vs {np.mean(xb):.4f} "
                  f"({np.mean(xa) / np.mean(xb) - 1:+.2%}), t = {t:.2f}, detects {d:.2%}")
            if abs(t) > limit:
                failures.append(f"{a} vs {b}, {region}: t = {t:.2f}, limit {limit:.2f}")
            if d >= REQUIRED[region]:
                weak.append(f"{a} vs {b}, {region}: detects {d:.2%}, required {REQUIRED[region]:.0%}")
            scale = 1 + math.copysign(REQUIRED[region], np.mean(xa) - np.mean(xb))
            t2, df2, _ = tc.welch(xa * scale, xb)
            if abs(t2) <= tc.student_t_quantile(1 - tc.FAMILY_ALPHA / (2 * comparisons), df2):
                weak.append(f"{a} vs {b}, {region}: sppm x {scale} passes (t = {t2:.2f})")
    assert not failures, "\n".join(failures)
    assert not weak, "\n".join(weak) + f"\ndetectable: {detectable}"


def test_sppm_caustic_is_brighter_than_the_shadow_and_the_open_floor(runs):
    caustic = [m["caustic"] for m in runs["sppm"]]
    for other in ("shadow", "lit"):
        t, df, _ = tc.welch(caustic, [m[other] for m in runs["sppm"]])
        assert t > tc.student_t_quantile(1 - tc.FAMILY_ALPHA / 2, df), other
