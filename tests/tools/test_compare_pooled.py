"""compare(pooled=True): a cheap TEST against a costly REFERENCE. On synthetic images whose
pixels are means of skewed samples (exponential, skewness 2, like path contributions),
Welch's t is biased when the spp differ (a pixel whose samples came out low also has a low
sample variance), and Stouffer's sum over the image adds the bias up: Welch finds a
difference that is not there. The pooled variance does not; a 2 % brighter TEST is
still found (the negative control)."""
from __future__ import annotations

import numpy as np

from tessera_tools import compare
from tessera_base import images


def image(rng, n: int, scale: float = 1.0, size: int = 64) -> images.RenderImage:
    samples = rng.exponential(scale, size=(size, size, 3, n))
    rgba = np.concatenate([samples.mean(axis=3), np.ones((size, size, 1))], axis=2)
    return images.RenderImage(rgba.astype(np.float32), samples.var(axis=3, ddof=1).astype(np.float32),
                              np.full((size, size), n, np.float32), {"tessera:integrator": "path"},
                              images.VARIANCE_PER_SAMPLE)


def test_pooled_variance_removes_the_bias_of_unequal_spp():
    rng = np.random.default_rng(11)
    reference = image(rng, 1024)
    verdicts = {"welch": 0, "pooled": 0}
    for _ in range(5):
        test = image(rng, 64)
        verdicts["welch"] += compare.compare_images(test, reference, flip=False).report.differs
        verdicts["pooled"] += compare.compare_images(test, reference, flip=False, pooled=True).report.differs
    assert verdicts["welch"] == 5      # the bias this option is for
    assert verdicts["pooled"] == 0     # 5 comparisons at alpha 0.01: P(any alarm) < 5 %


def test_pooled_still_finds_two_percent():
    rng = np.random.default_rng(12)
    reference = image(rng, 1024)
    found = sum(compare.compare_images(image(rng, 64, scale=1.02), reference, flip=False,
                                       pooled=True).report.differs for _ in range(5))
    assert found == 5
