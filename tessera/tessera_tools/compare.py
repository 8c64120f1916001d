"""Noise-aware comparison of two renders: do TEST and REFERENCE differ beyond their noise?

Both images carry a per-pixel noise estimate (images.VARIANCE_CHANNELS, images.SPP_CHANNEL)
of the kind their header names (images.VARIANCE_ATTRIBUTE): "per-sample" (the variance of
one sample: the pixel's mean a has the variance s_a = var_a / n_a, n_a - 1 degrees of
freedom) or "batch-means:K" (light, bdpt: s_a is the layer itself, K - 1 degrees of
freedom). Images of no or an unknown kind are refused. Per pixel and channel

    t = (a - b) / sqrt(s_a + s_b)

is Welch's t statistic, with the Welch-Satterthwaite degrees of freedom (Jung, Hanika and
Dachsbacher, "Detecting Bias in Monte Carlo Renderers using Welch's t-test", JCGT 2020;
Mitsuba's render tests compare against a reference with a variance image in the same
spirit). A Student-t p-value rather than a normal one matters at low spp: with 16 samples
the t tail at |t| = 5 is ~1000x heavier than the normal tail.

One pixel at a time has little power against a small change spread over many pixels (an
albedo 5 % off), so the same test also runs on sums over blocks of 4x4 and 16x16 pixels and
over the whole image. A block's statistic is Stouffer's combination sum(z) / sqrt(m) of its m
noisy pixel-channels, each pixel's t turned into the standard normal z of the same tail
probability; unlike a plain sum of pixel values this weighs every pixel alike, so a
block is not drowned by its noisiest pixels (a light's edge). Multiple comparisons: within each of these L = 4
scales the p-values go through the Benjamini-Hochberg procedure at level alpha / L, and the
images "differ" when any scale rejects any hypothesis. Why BH: under the null (the
renderers agree) the blocks of one scale are independent, and then BH rejects anything with
probability exactly alpha / L, the same family-wise false-alarm rate as Bonferroni; but when
many pixels differ a little it rejects far more of them (it controls the false discovery
rate, not the chance of a single false alarm), so it is the more powerful of the two at the
same CI false-alarm rate. Bonferroni (`method="bonferroni"`) is there for the cautious. The
union over the L scales is a Bonferroni split, so the overall false-alarm rate is <= alpha.

Pixels with zero variance in both images (background, a directly seen light, spp = 1) carry
no noise estimate: they must agree to float rounding, |a - b| <= ATOL + RTOL * max(|a|, |b|)
(1e-6 and 1e-5). Every other pixel's variance gets that same tolerance squared added, so a
nearly deterministic pixel is not flagged for a last-bit difference. A pixel that is NaN or
Inf (colour or variance) in either image makes the images differ.

Also reported, not used for the verdict: RMSE and relMSE (mean of (a - b)^2 / (b^2 + 0.01))
over the finite pixels, and LDR FLIP (NVIDIA's flip-evaluator package, on the sRGB previews
as `tessera render` writes them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from tessera_base import images, integrators

ALPHA = 0.01
BLOCK_SIZES = (1, 4, 16, 0)      # pixels per block side; 0: the whole image
ATOL, RTOL = 1e-6, 1e-5
RELMSE_EPSILON = 0.01
MAX_PIXELS = 1 << 26             # 64 Mpx: larger images are refused before being decoded

Method = Literal["bh", "bonferroni"]


class CompareError(ValueError):
    """The comparison cannot be made (missing file, size mismatch, no variance channels):
    a usage error (exit code 2, HTTP 422), not a verdict."""


class ScaleResult(BaseModel):
    block: int = Field(description="block edge in pixels; 0: the whole image")
    tests: int = Field(description="hypotheses tested at this scale (blocks x channels with noise)")
    significant: int = Field(description="hypotheses rejected at this scale")
    min_p: float | None = Field(description="the smallest p-value at this scale")
    max_abs_t: float | None = Field(description="the largest |t| (1x1) or |Stouffer z| at this scale")


class CompareReport(BaseModel):
    """The outcome of comparing TEST with REFERENCE."""

    verdict: Literal["same", "differs"]
    reasons: list[str] = Field(description="why the images differ (empty when the same)")
    method: Method
    alpha: float = Field(description="overall false-alarm rate when the renderers agree")
    width: int
    height: int
    test_spp: float = Field(description="mean samples per pixel of TEST")
    reference_spp: float = Field(description="mean samples per pixel of REFERENCE")
    scales: list[ScaleResult]
    significant_pixels: int = Field(description="pixels with a channel rejected at the 1x1 scale")
    nonfinite_pixels: int = Field(description="pixels NaN/Inf in colour or variance in either image")
    exact_mismatch_pixels: int = Field(description="zero-variance pixels that differ beyond rounding")
    first_difference: tuple[int, int] | None = Field(
        description="(x, y) of the most significant differing pixel, if any")
    rmse: float | None
    relmse: float | None
    flip: float | None = Field(description="mean LDR FLIP of the sRGB previews (0 = identical)")
    mean_test: list[float]
    mean_reference: list[float]
    pooled: bool = Field(default=False, description="both sides judged with one pooled per-sample "
                                                    "variance (compare_images' `pooled`)")

    @property
    def differs(self) -> bool:
        return self.verdict == "differs"

    def summary(self) -> str:
        lines = [f"{self.verdict.upper()}: {self.width}x{self.height}, TEST {self.test_spp:g} spp, "
                 f"REFERENCE {self.reference_spp:g} spp; "
                 f"{'t-test with pooled variance' if self.pooled else 'Welch t-test'}, "
                 f"{'Benjamini-Hochberg' if self.method == 'bh' else 'Bonferroni'} at alpha {self.alpha:g}"]
        for s in self.scales:
            name = "image" if s.block == 0 else f"{s.block}x{s.block}"
            t = "-" if s.max_abs_t is None else f"{s.max_abs_t:.2f}"
            p = "-" if s.min_p is None else f"{s.min_p:.2e}"
            lines.append(f"  {name:>7}: {s.significant}/{s.tests} significant (max |t| {t}, min p {p})")
        lines.append(f"  non-finite pixels {self.nonfinite_pixels}, zero-variance mismatches "
                     f"{self.exact_mismatch_pixels}")
        fmt = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
        lines.append(f"  RMSE {fmt(self.rmse)}, relMSE {fmt(self.relmse)}, FLIP {fmt(self.flip)}")
        lines += [f"  - {r}" for r in self.reasons]
        return "\n".join(lines)


@dataclass
class Comparison:
    """A report and the per-pixel maps behind it (for the heatmap)."""
    report: CompareReport
    max_abs_t: np.ndarray        # (h, w): the largest |t| of the pixel's channels
    significant: np.ndarray      # (h, w) bool: rejected at the 1x1 scale or a mismatch
    in_significant_block: np.ndarray  # (h, w) bool: inside a rejected coarser block
    nonfinite: np.ndarray        # (h, w) bool


def load(path: str | Path, role: str) -> images.RenderImage:
    """Reads one side of a comparison; CompareError for anything but a usable render."""
    path = Path(path)
    if not path.is_file():
        raise CompareError(f"{role} {path}: no such file")
    try:
        image = images.read_render(path, max_pixels=MAX_PIXELS)
    except (OSError, ValueError) as exc:
        raise CompareError(f"{role} {path}: {exc}") from None
    if image.variance is None or image.spp is None:
        raise CompareError(
            f"{role} {path} has no variance channels ({', '.join(images.VARIANCE_CHANNELS)} and "
            f"{images.SPP_CHANNEL}): render it with `tessera render` (any integrator), or on the "
            f"farm with the variance and spp AOVs (`tessera submit --aovs variance,spp`)")
    _check_variance(image, f"{role} {path}")
    return image


def _check_variance(image: images.RenderImage, role: str) -> tuple[str, int | None]:
    """The image's variance kind (images.parse_variance_kind); CompareError when the
    image cannot be judged: no variance, no or an unknown tessera:variance kind, or a
    per-sample variance from an integrator that splats (it misses the splats)."""
    if image.variance is None or image.spp is None:
        raise CompareError(f"{role} has no variance channels")
    kind = image.variance_kind
    if kind is None:
        raise CompareError(
            f"{role} does not say what its variance channels mean (no {images.VARIANCE_ATTRIBUTE} "
            f"header attribute: written by an older Tessera, whose light and bdpt variance missed "
            f"the splats); render it again with this version")
    try:
        parsed = images.parse_variance_kind(kind)
    except ValueError as exc:
        raise CompareError(f"{role}: {exc}; render it again with this version") from None
    integrator = image.metadata.get("tessera:integrator", "")
    splatting = integrator in integrators.names() and integrators.splats(integrator)
    if parsed[0] == images.VARIANCE_PER_SAMPLE and splatting:
        raise CompareError(f"{role} was rendered with {integrator} but carries a per-sample "
                           f"variance, which misses its splats; render it again with this version")
    return parsed


def compare_files(test: str | Path, reference: str | Path, *, alpha: float = ALPHA,
                  method: Method = "bh", flip: bool = True, pooled: bool = False) -> Comparison:
    return compare_images(load(test, "TEST"), load(reference, "REFERENCE"), alpha=alpha,
                          method=method, flip=flip, pooled=pooled)


def compare_images(test: images.RenderImage, reference: images.RenderImage, *, alpha: float = ALPHA,
                   method: Method = "bh", flip: bool = True, pooled: bool = False) -> Comparison:
    """`pooled`: judge both sides with one per-sample variance, pooled from the two
    estimates (_pool_variance); valid under the hypothesis tested (the same renderer, so
    the same per-sample distribution) and needed when the spp differ a lot (a cheap TEST
    against a costly REFERENCE), where Welch's t is biased (see _pool_variance)."""
    if not 0.0 < alpha < 1.0:
        raise CompareError(f"alpha must lie in (0, 1), not {alpha}")
    if method not in ("bh", "bonferroni"):
        raise CompareError(f"unknown method {method!r} (known: bh, bonferroni)")
    if test.rgba.shape[:2] != reference.rgba.shape[:2]:
        (h1, w1), (h2, w2) = test.rgba.shape[:2], reference.rgba.shape[:2]
        raise CompareError(f"TEST is {w1}x{h1} but REFERENCE is {w2}x{h2}")
    kinds = [_check_variance(img, role) for role, img in (("TEST", test), ("REFERENCE", reference))]
    from scipy import stats

    h, w = test.rgba.shape[:2]
    a = test.rgba[..., :3].astype(np.float64)
    b = reference.rgba[..., :3].astype(np.float64)
    na = np.broadcast_to(test.spp.astype(np.float64)[..., None], a.shape)
    nb = np.broadcast_to(reference.spp.astype(np.float64)[..., None], b.shape)
    with np.errstate(all="ignore"):
        va = test.variance.astype(np.float64)
        vb = reference.variance.astype(np.float64)
        bad = ~(np.isfinite(a) & np.isfinite(b) & np.isfinite(va) & np.isfinite(vb)
                & (va >= 0) & (vb >= 0) & (na >= 1) & (nb >= 1))
        nonfinite = bad.any(axis=2)
        ok = ~nonfinite[..., None] & np.ones_like(bad)
        a, b = np.where(ok, a, 0.0), np.where(ok, b, 0.0)
        # Each side's variance of the mean and its degrees of freedom: per-sample variance
        # / spp with spp - 1, or a batch-means variance as it is with K - 1.
        (sa, fa), (sb, fb) = (_mean_variance(v, n, ok, kind)
                              for v, n, kind in ((va, na, kinds[0]), (vb, nb, kinds[1])))
        if pooled:
            sa, fa, sb, fb = _pool_variance(sa, fa, na, sb, fb, nb, ok)
        # Welch-Satterthwaite denominators: s^2 / df; zero where a side has no noise.
        qa = np.where(ok & (fa >= 1), sa * sa / np.maximum(fa, 1.0), 0.0)
        qb = np.where(ok & (fb >= 1), sb * sb / np.maximum(fb, 1.0), 0.0)
        d = a - b
        tol = ATOL + RTOL * np.maximum(np.abs(a), np.abs(b))
        deterministic = ok & (sa + sb == 0.0)
        mismatch = deterministic & (np.abs(d) > tol)
        noisy = ok & ~deterministic
        s = np.where(noisy, sa + sb + tol * tol, 0.0)
        q = np.where(noisy, qa + qb, 0.0)
        d = np.where(noisy, d, 0.0)

    # The pixel test: Welch's t with its Welch-Satterthwaite df (infinite, i.e. normal, when
    # no side has an estimated variance term), and the same evidence as a standard normal z
    # (the t quantile mapped to the normal quantile of equal tail probability).
    from scipy.special import ndtri_exp

    t = np.zeros_like(d)
    t[noisy] = d[noisy] / np.sqrt(s[noisy])
    with np.errstate(divide="ignore", invalid="ignore"):
        df = np.where(q > 0, s * s / np.where(q > 0, q, 1.0), np.inf)
    df = np.maximum(df, 1.0)
    log_tail = np.zeros_like(d)                     # log P(T > |t|)
    log_tail[noisy] = stats.t.logsf(np.abs(t[noisy]), df[noisy])
    z = np.where(noisy, -np.sign(t) * ndtri_exp(np.minimum(log_tail, np.log(0.5))), 0.0)
    pixel_p = np.minimum(1.0, 2.0 * np.exp(log_tail))

    scales, rejected_maps = [], []
    n_scales = len(BLOCK_SIZES)
    for block in BLOCK_SIZES:
        k_y, k_x = (h, w) if block == 0 else (block, block)
        if block == 1:
            stat, p, tested = t, pixel_p, noisy
        else:
            # Stouffer's combination of the pixels' z: every noisy pixel weighs the same
            # whatever its variance, so a block is not drowned by its noisiest pixel (a
            # light's edge) the way a plain sum of pixel values would be.
            m = _block_sums(noisy.astype(np.float64), k_y, k_x)
            tested = m > 0
            stat = np.where(tested, _block_sums(z, k_y, k_x) / np.sqrt(np.maximum(m, 1.0)), 0.0)
            p = np.where(tested, 2.0 * stats.norm.sf(np.abs(stat)), 1.0)
        reject = np.zeros(tested.shape, bool)
        reject[tested] = _reject(p[tested], alpha / n_scales, method)
        scales.append(ScaleResult(block=block, tests=int(tested.sum()), significant=int(reject.sum()),
                                  min_p=float(p[tested].min()) if tested.any() else None,
                                  max_abs_t=float(np.abs(stat[tested]).max()) if tested.any() else None))
        # Back to pixels: which pixels lie in a rejected block (any channel).
        up = np.repeat(np.repeat(reject.any(axis=2), k_y, axis=0), k_x, axis=1)[:h, :w]
        rejected_maps.append(up)
    pixel_t = np.abs(t).max(axis=2)

    significant = rejected_maps[0] | mismatch.any(axis=2)
    coarse = np.zeros((h, w), bool)
    for m in rejected_maps[1:]:
        coarse |= m
    reasons = []
    if nonfinite.any():
        y, x = np.argwhere(nonfinite)[0]
        reasons.append(f"{int(nonfinite.sum())} pixels are NaN/Inf in either image (first at x={x}, y={y})")
    if mismatch.any():
        reasons.append(f"{int(mismatch.any(axis=2).sum())} zero-variance pixels differ beyond rounding")
    for sr in scales:
        if sr.significant:
            name = "the whole image" if sr.block == 0 else f"{sr.block}x{sr.block} blocks"
            reasons.append(f"{sr.significant} of {sr.tests} tests on {name} differ beyond noise "
                           f"(min p {sr.min_p:.2e})")
    first = None
    score = np.where(mismatch.any(axis=2) | nonfinite, np.inf, np.where(significant, pixel_t, -1.0))
    if score.max() >= 0 and (significant.any() or nonfinite.any()):
        y, x = np.unravel_index(int(np.argmax(score)), score.shape)
        first = (int(x), int(y))

    finite_px = ~nonfinite
    rmse = relmse = None
    if finite_px.any():
        diff = (test.rgba[..., :3].astype(np.float64) - reference.rgba[..., :3].astype(np.float64))[finite_px]
        ref = reference.rgba[..., :3].astype(np.float64)[finite_px]
        rmse = float(np.sqrt(np.mean(diff ** 2)))
        relmse = float(np.mean(diff ** 2 / (ref ** 2 + RELMSE_EPSILON)))

    def mean_rgb(img):
        rgb = img.rgba[..., :3].astype(np.float64)[finite_px]
        return [float(v) for v in rgb.mean(axis=0)] if len(rgb) else [math.nan] * 3

    report = CompareReport(
        verdict="differs" if reasons else "same", reasons=reasons, method=method, alpha=alpha,
        width=w, height=h, test_spp=float(np.mean(test.spp)), reference_spp=float(np.mean(reference.spp)),
        scales=scales, significant_pixels=int(significant.sum()), nonfinite_pixels=int(nonfinite.sum()),
        exact_mismatch_pixels=int(mismatch.any(axis=2).sum()), first_difference=first,
        rmse=rmse, relmse=relmse, flip=flip_error(test.rgba, reference.rgba) if flip else None,
        mean_test=[v if math.isfinite(v) else 0.0 for v in mean_rgb(test)],
        mean_reference=[v if math.isfinite(v) else 0.0 for v in mean_rgb(reference)], pooled=pooled)
    return Comparison(report, pixel_t, significant, coarse & ~significant, nonfinite)


def _mean_variance(var: np.ndarray, n: np.ndarray, ok: np.ndarray,
                   kind: tuple[str, int | None]) -> tuple[np.ndarray, np.ndarray]:
    """(variance of the pixel's mean, its degrees of freedom) of one side."""
    if kind[0] == images.VARIANCE_PER_SAMPLE:
        return np.where(ok, var / np.where(ok, n, 1.0), 0.0), n - 1.0
    return np.where(ok, var, 0.0), np.full_like(var, float(kind[1] - 1))


def _pool_variance(sa, fa, na, sb, fb, nb, ok):
    """Both sides' variance of the mean from one per-sample variance, the two sides'
    estimates pooled by their degrees of freedom; each side then carries half of the
    pooled df, so Welch-Satterthwaite gives about fa + fb. Why: a low-spp TEST's sample
    variance is correlated with its mean (skewed path contributions: the samples that miss
    a rare bright path give both a low mean and a low variance), so E[t] < 0 per pixel and
    Stouffer's sum over a block or the image adds that bias up (measured: Cornell 64x64,
    16 spp against 1024 spp, whole-image p 1e-194 with nothing changed). With the pooled
    variance, dominated by the high-spp side, the denominator hardly depends on TEST's mean."""
    total = np.maximum(fa + fb, 1.0)
    sigma2 = np.where(ok, (fa * sa * na + fb * sb * nb) / total, 0.0)
    return (np.where(ok, sigma2 / np.maximum(na, 1.0), 0.0), total / 2.0,
            np.where(ok, sigma2 / np.maximum(nb, 1.0), 0.0), total / 2.0)


def _block_sums(x: np.ndarray, k_y: int, k_x: int) -> np.ndarray:
    """Sums over k_y x k_x blocks of an (h, w, c) array (edge blocks are smaller)."""
    h, w, c = x.shape
    hp, wp = -(-h // k_y) * k_y, -(-w // k_x) * k_x
    if (hp, wp) != (h, w):
        x = np.pad(x, ((0, hp - h), (0, wp - w), (0, 0)))
    return x.reshape(hp // k_y, k_y, wp // k_x, k_x, c).sum(axis=(1, 3))


def _reject(p: np.ndarray, level: float, method: Method) -> np.ndarray:
    """Which of the p-values are rejected at family level `level`."""
    m = p.size
    if m == 0:
        return np.zeros(0, bool)
    if method == "bonferroni":
        return p <= level / m
    order = np.argsort(p, kind="stable")
    below = p[order] <= level * np.arange(1, m + 1) / m
    out = np.zeros(m, bool)
    if below.any():
        k = int(np.nonzero(below)[0].max())
        out[order[:k + 1]] = True
    return out


def flip_error(test_rgba: np.ndarray, reference_rgba: np.ndarray) -> float | None:
    """Mean LDR FLIP between the sRGB previews (images.tonemap_srgb8) of two renders, with
    NVIDIA's flip-evaluator at its default viewing conditions (67 pixels per degree).
    None when an image is too small for FLIP's filters."""
    import flip_evaluator

    ref = images.tonemap_srgb8(reference_rgba).astype(np.float32) / 255.0
    tst = images.tonemap_srgb8(test_rgba).astype(np.float32) / 255.0
    _, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref), np.ascontiguousarray(tst), "LDR",
                                         inputsRGB=True, applyMagma=False, computeMeanError=True)
    return float(mean) if math.isfinite(mean) else None


def heatmap(comparison: Comparison) -> np.ndarray:
    """An (h, w, 3) uint8 picture of the comparison: grey level |t| / 6 of the pixel test,
    orange inside rejected 4x4/16x16/image blocks, red for pixels rejected on their own or
    differing with zero variance, magenta for NaN/Inf."""
    grey = np.clip(comparison.max_abs_t / 6.0, 0.0, 1.0)
    out = np.repeat((grey * 200.0)[..., None], 3, axis=2)
    orange = np.array([255.0, 150.0, 0.0])
    out[comparison.in_significant_block] = 0.5 * out[comparison.in_significant_block] + 0.5 * orange
    out[comparison.significant] = (255, 0, 0)
    out[comparison.nonfinite] = (255, 0, 255)
    return np.round(out).astype(np.uint8)
