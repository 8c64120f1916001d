"""The bench's statistics: relMSE and RMSE against a reference, the region means that
check two renderers agree in units, log-log fits and what is read off them."""
from __future__ import annotations

import math
import statistics

import numpy as np

UNIT_TOLERANCE = 0.01          # converged means must agree within 1 %
REGIONS = 4                    # 4 x 4 regions for the per-region means
TARGETS = (1e-2, 1e-3)         # relMSE targets whose time-to-reach is reported


# -- errors --------------------------------------------------------------------------------

def rel_mse(img: np.ndarray, ref: np.ndarray) -> float:
    """Mean over pixels and channels of (x - ref)^2 / (ref^2 + 1e-2)."""
    x, r = img[..., :3].astype(np.float64), ref[..., :3].astype(np.float64)
    return float(np.mean((x - r) ** 2 / (r * r + 1e-2)))


def reference_noise(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The relMSE that the mean of two independent references a and b has on its own, and
    that estimate's standard error: mean over pixels and channels of (a - b)^2 / 4 /
    (m^2 + 1e-2), m = (a + b) / 2. For an image x independent of both, E[relMSE(x, m)] is
    x's own relMSE plus this (the cross term has mean zero), so subtracting it measures
    errors down to the reference's own instead of stopping at it."""
    x, y = a[..., :3].astype(np.float64), b[..., :3].astype(np.float64)
    m = (x + y) / 2
    d = ((x - y) ** 2 / 4 / (m * m + 1e-2)).reshape(-1)
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(d.size))


def rmse(img: np.ndarray, ref: np.ndarray) -> float:
    x, r = img[..., :3].astype(np.float64), ref[..., :3].astype(np.float64)
    return float(np.sqrt(np.mean((x - r) ** 2)))


def region_means(img: np.ndarray, n: int = REGIONS) -> np.ndarray:
    """(n, n, 3) channel means over an n x n grid of regions."""
    h, w = img.shape[:2]
    ys = np.linspace(0, h, n + 1).astype(int)
    xs = np.linspace(0, w, n + 1).astype(int)
    return np.array([[img[ys[i]:ys[i + 1], xs[j]:xs[j + 1], :3].astype(np.float64).mean((0, 1))
                      for j in range(n)] for i in range(n)])


def units_agree(a: np.ndarray, b: np.ndarray, tolerance: float = UNIT_TOLERANCE,
                noise: np.ndarray | None = None) -> dict:
    """Compares two converged images of the same scene: the ratio b/a of the image means
    (per channel) and of every region's mean (luminance-weighted channels summed, regions
    with less than 2 % of the image's mean excluded as too dark to matter). With `noise`
    (REGIONS x REGIONS: the relative standard error of each region's ratio, from the two
    images' own noise) a region agrees within tolerance + 3 noise: at 64 px a caustic's
    region of a converged path-traced image is itself a few percent noisy, and a 1 % check
    alone cannot tell that from a unit error."""
    mean_a, mean_b = a[..., :3].astype(np.float64).mean((0, 1)), b[..., :3].astype(np.float64).mean((0, 1))
    channel_ratio = mean_b / np.maximum(mean_a, 1e-30)
    ra, rb = region_means(a).sum(-1), region_means(b).sum(-1)
    lit = ra > 0.02 * ra.mean()
    region_ratio = np.where(lit, rb / np.maximum(ra, 1e-30), np.nan)
    deviation = np.abs(region_ratio - 1.0)
    # What a region deviates beyond its noise (3 standard errors).
    excess = deviation - (3 * np.nan_to_num(np.asarray(noise, np.float64)) if noise is not None else 0.0)
    worst = float(np.nanmax(deviation)) if lit.any() else float("nan")
    worst_excess = float(np.max(excess[lit])) if lit.any() else float("nan")
    worst_mean = float(np.max(np.abs(channel_ratio - 1.0)))
    out = {"mean_ratio": channel_ratio.tolist(), "region_ratio": region_ratio.tolist(),
           "worst_mean_deviation": worst_mean, "worst_region_deviation": worst,
           "regions_compared": int(lit.sum()), "tolerance": tolerance,
           "agree": bool(worst_mean <= tolerance and worst_excess <= tolerance)}
    if noise is not None:
        out["region_noise"] = np.asarray(noise, np.float64).tolist()
        out["worst_region_excess"] = worst_excess
    return out


def region_noise(pass_images=None, halves=None) -> np.ndarray:
    """The relative standard error of each region's mean (luminance-weighted channels
    summed) of an image that is the mean of `pass_images` (equal-sample passes: their
    spread), or of the two `halves` (a, b): |a - b| / (a + b) per region, a one-sample
    estimate of the standard error of their mean."""
    if pass_images is not None:
        r = np.stack([region_means(p).sum(-1) for p in pass_images])
        return r.std(axis=0, ddof=1) / np.sqrt(len(r)) / np.maximum(np.abs(r.mean(axis=0)), 1e-30)
    ra, rb = (region_means(h).sum(-1) for h in halves)
    return np.abs(ra - rb) / np.maximum(ra + rb, 1e-30)


# -- fits ----------------------------------------------------------------------------------

def fit_loglog(seconds, errors) -> tuple[float, float]:
    """(intercept a, slope b) of log10(error) = a + b log10(seconds), least squares."""
    x, y = np.log10(np.asarray(seconds, float)), np.log10(np.asarray(errors, float))
    b, a = np.polyfit(x, y, 1)
    return float(a), float(b)


FLAT_SLOPE = -0.2   # a fit flatter than this cannot be extrapolated to a target: no time


def time_to(fit, target: float) -> float:
    a, b = fit
    return 10 ** ((math.log10(target) - a) / b) if b < FLAT_SLOPE else float("inf")


def time_to_measured(seconds, errors, target: float, fit) -> tuple[float, str]:
    """Seconds to reach `target` read between the measured points where the curve first
    crosses it (log-log interpolation between the two neighbours, in order of seconds):
    a ladder's global line would bend the reading for an integrator whose slope changes
    along the way (a merging one's bias takes over late). Off the measured range, the
    line `fit`. Returns (seconds, "interpolated" or "extrapolated")."""
    pts = sorted(zip(seconds, errors))
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 > target >= e1 > 0:
            u = (math.log10(target) - math.log10(e0)) / (math.log10(e1) - math.log10(e0))
            return 10 ** (math.log10(t0) + u * (math.log10(t1) - math.log10(t0))), "interpolated"
    return time_to(fit, target), "extrapolated"


def error_at(fit, seconds: float) -> float:
    a, b = fit
    return 10 ** (a + b * math.log10(seconds))


def spread(values) -> dict:
    v = [x for x in values if math.isfinite(x)]
    if not v:
        return {"median": float("nan"), "half_range": float("nan"), "n": 0}
    return {"median": statistics.median(v), "half_range": (max(v) - min(v)) / 2, "n": len(v)}


def fmt(s: dict, digits: int = 3) -> str:
    if not s["n"]:
        return "—"
    return f"{s['median']:.{digits}g} ± {s['half_range']:.2g}"


# -- references ----------------------------------------------------------------------------
