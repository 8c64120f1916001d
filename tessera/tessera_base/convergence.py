"""How passes combine and when a render has converged: per-tile means and variances
(combine_passes, combine_aovs), per-tile noise targets, and the batch-means estimate of a
lockstep job's whole-image error; and when a render stops (tile_stops, image_stops: noise
target, max_spp and time limit, for local renders and workers alike)."""
from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .protocol import AOV_CHANNELS, RenderSettings, TileResult, pass_range


# ------------------------------------------------------------------ combining passes
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def combine_passes(passes: list[TileResult]) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Combines passes of one tile (in pass order) into (rgba float32, variance or None,
    total samples): the sample-count-weighted mean, computed in float64. One pass is
    returned as it is, so a fixed-spp image is exactly the renderer's output."""
    passes = sorted(passes, key=lambda p: p.pass_index)
    if len(passes) == 1:
        p = passes[0]
        return p.rgba, p.variance, p.spp
    counts = [p.spp for p in passes]
    if min(counts) < 1:
        raise ValueError("cannot combine passes without sample counts")
    total = sum(counts)
    mean = sum(n * p.rgba.astype(np.float64) for n, p in zip(counts, passes)) / total
    variance = None
    if all(p.variance is not None for p in passes) and total > 1:
        # Chan et al.: pooled sum of squared deviations of the combined sample set.
        m2 = sum((n - 1) * p.variance.astype(np.float64)
                 + n * (p.rgba[..., :3].astype(np.float64) - mean[..., :3]) ** 2
                 for n, p in zip(counts, passes))
        variance = (m2 / (total - 1)).astype(np.float32)
    return mean.astype(np.float32), variance, total


def combine_aovs(passes: list[TileResult]) -> dict[str, np.ndarray]:
    """Combines the AOVs of one tile's passes (docs/aovs.md): albedo and normal as the
    sample-count-weighted mean; spp as the sum; depth as the mean over the samples that hit
    something, each pass weighted by its hit count spp * alpha (+inf where none hit). One
    pass is returned as it is. Every pass must carry the same AOVs."""
    passes = sorted(passes, key=lambda p: p.pass_index)
    names = set(passes[0].aovs or {})
    if any(set(p.aovs or {}) != names for p in passes):
        raise ValueError("passes of one tile carry different AOVs")
    if len(passes) == 1 or not names:
        return dict(passes[0].aovs or {})
    counts = [p.spp for p in passes]
    if min(counts) < 1:
        raise ValueError("cannot combine passes without sample counts")
    total = sum(counts)
    out = {}
    for name in names:
        layers = [p.aovs[name].astype(np.float64).reshape(*p.rgba.shape[:2], -1) for p in passes]
        if name == "spp":
            out[name] = sum(layers).astype(np.float32)
        elif name == "depth":
            hits = [n * p.rgba[..., 3:4].astype(np.float64) for n, p in zip(counts, passes)]
            weight = sum(hits)
            num = sum(k * np.where(k > 0, d, 0.0) for k, d in zip(hits, layers))  # no 0 * inf
            with np.errstate(invalid="ignore", divide="ignore"):
                out[name] = np.where(weight > 0, num / np.where(weight > 0, weight, 1.0),
                                     np.inf).astype(np.float32)
        else:
            out[name] = (sum(n * a for n, a in zip(counts, layers)) / total).astype(np.float32)
    return out


def new_aov_frame(settings: RenderSettings) -> dict[str, np.ndarray]:
    """Full-frame float32 buffers for the job's AOVs (AOV layers are (h, w, c))."""
    channels = dict(AOV_CHANNELS, variance=3)
    return {name: np.zeros((settings.height, settings.width, channels[name]), np.float32)
            for name in settings.aovs}


def tile_error(rgba: np.ndarray, variance: np.ndarray, samples: int) -> float:
    """The tile's relative noise: the RMS over its pixels of (standard error of the pixel's
    luminance) / (its luminance), with luminances floored at 1 % of the tile's mean (and
    1e-4) so that black pixels do not dominate. A tile without variance (background) is 0."""
    lum = rgba[..., :3].astype(np.float64) @ _LUMINANCE
    var_mean = (variance.astype(np.float64) @ (_LUMINANCE ** 2)) / max(samples, 1)
    floor = max(1e-4, 0.01 * float(np.mean(np.abs(lum))))
    rel = var_mean / np.maximum(np.abs(lum), floor) ** 2
    return float(np.sqrt(np.mean(rel)))


def tile_finished(settings: RenderSettings, pass_index: int, rgba: np.ndarray,
                  variance: np.ndarray | None, samples: int) -> bool:
    """Whether a tile needs no further pass after `pass_index` (timing aside)."""
    if pass_range(settings, pass_index + 1) is None:
        return True
    if variance is None:
        return False
    return tile_error(rgba, variance, samples) <= settings.target_error


# ------------------------------------------------------------------ lockstep passes
# A lockstep job's error is judged on whole-image pass estimates (batch means): pass p's
# image I_p (camera part of every tile + that pass's splats over its own light paths) is an
# independent estimate with variance sigma^2 / n_p. With N = sum n_p and the weighted mean
# M = sum n_p I_p / N, E[sum n_p (I_p - M)^2] = (K - 1) sigma^2, so
#   Var(M) ~= (S2 - S1^2 / N) / ((K - 1) N),  S1 = sum n_p I_p,  S2 = sum n_p I_p^2,
# per pixel on luminance. Owen-scrambled passes are not quite independent (their union is
# better stratified than each), which makes this estimate conservative.

def variance_of_mean(s1: np.ndarray, s2: np.ndarray, samples: int, batches: int) -> np.ndarray:
    """The batch-means estimate above: Var(M) ~= (S2 - S1^2 / N) / ((K - 1) N), float64,
    from S1 = sum n_k I_k, S2 = sum n_k I_k^2 over K >= 2 batches of N samples in all."""
    n = float(samples)
    return np.maximum(s2 - s1 * (s1 / n), 0.0) / (batches - 1) / n


# Every image's noise estimate for the splatting integrators (light, bdpt; auto when it
# resolves to one): a light path splats onto other pixels than its camera sample's, so a
# pixel's per-sample variance describes only its camera half. Instead every pass's sample
# range is also rendered as VARIANCE_BATCHES independent sub-ranges (batches), each a whole
# image of its own (camera part + its own splats normalised by its own light paths); the
# spread of the batch images per pixel estimates the variance of the pixel's mean with
# K - 1 degrees of freedom (K batches in all). The image itself is rendered as before.
VARIANCE_BATCHES = 8


def batch_ranges(sample_start: int, spp: int, batches: int = VARIANCE_BATCHES) -> list[tuple[int, int]]:
    """A pass's samples [sample_start, sample_start + spp) as min(batches, spp) contiguous
    (start, count) ranges of near-equal size."""
    k = max(1, min(batches, spp))
    base, extra = divmod(spp, k)
    out, start = [], sample_start
    for j in range(k):
        n = base + (1 if j < extra else 0)
        out.append((start, n))
        start += n
    return out


@dataclass
class BatchMeans:
    """Per-pixel, per-channel running sums over independent batch images (S1, S2 above)."""

    batches: int = 0
    samples: int = 0
    s1: np.ndarray | None = None  # float64: sum n_k I_k
    s2: np.ndarray | None = None  # float64: sum n_k I_k^2

    def add(self, image: np.ndarray, n: int) -> None:
        x = np.asarray(image, dtype=np.float64)
        if self.s1 is None:
            self.s1, self.s2 = np.zeros_like(x), np.zeros_like(x)
        self.s1 += n * x
        self.s2 += n * x * x
        self.batches += 1
        self.samples += n

    def variance_of_mean(self) -> np.ndarray | None:
        """float32 estimated variance of the mean of all batches; None below 2 batches."""
        if self.batches < 2 or self.s1 is None:
            return None
        return variance_of_mean(self.s1, self.s2, self.samples, self.batches).astype(np.float32)


@dataclass
class PassAccumulator:
    """Running sums over the passes of a lockstep job (see above); bytes round-trip so a
    farm keeps it in Redis between barriers."""

    passes: int = 0
    samples: int = 0
    s1: np.ndarray | None = None  # float64 (h, w): sum n_p lum(I_p)
    s2: np.ndarray | None = None  # float64 (h, w): sum n_p lum(I_p)^2

    def add(self, image: np.ndarray, spp: int) -> "PassAccumulator":
        lum = image[..., :3].astype(np.float64) @ _LUMINANCE
        s1 = spp * lum if self.s1 is None else self.s1 + spp * lum
        s2 = spp * lum * lum if self.s2 is None else self.s2 + spp * lum * lum
        return PassAccumulator(self.passes + 1, self.samples + spp, s1, s2)

    def error(self) -> float | None:
        """Relative noise of the image so far, as `tile_error` measures a tile; None before
        two passes (one pass cannot estimate its own variance)."""
        if self.passes < 2 or self.s1 is None:
            return None
        var_mean = variance_of_mean(self.s1, self.s2, self.samples, self.passes)
        mean = self.s1 / float(self.samples)
        floor = max(1e-4, 0.01 * float(np.mean(np.abs(mean))))
        return float(np.sqrt(np.mean(var_mean / np.maximum(np.abs(mean), floor) ** 2)))

    def to_bytes(self) -> bytes:
        if self.s1 is None:
            return struct.pack("<IQII", self.passes, self.samples, 0, 0)
        h, w = self.s1.shape
        return (struct.pack("<IQII", self.passes, self.samples, h, w)
                + zlib.compress(np.stack([self.s1, self.s2]).tobytes(), 1))

    @classmethod
    def from_bytes(cls, data: bytes | None) -> "PassAccumulator":
        if not data:
            return cls()
        passes, samples, h, w = struct.unpack_from("<IQII", data)
        if h == 0:
            return cls(passes, samples)
        arrays = np.frombuffer(zlib.decompress(data[struct.calcsize("<IQII"):]),
                               dtype=np.float64).reshape(2, h, w)
        return cls(passes, samples, arrays[0].copy(), arrays[1].copy())


def image_finished(settings: RenderSettings, pass_index: int, acc: PassAccumulator) -> bool:
    """Whether a lockstep job needs no pass after `pass_index` (timing aside); `acc` holds
    passes 0..pass_index."""
    if pass_range(settings, pass_index + 1) is None:
        return True
    if not settings.adaptive:  # a fixed spp in passes (a progressive integrator): all of them
        return False
    error = acc.error()
    return error is not None and error <= settings.target_error


# ------------------------------------------------------------------ when to stop
# The one place that enforces a render's stopping rules (noise target, max_spp, time
# limit) for local renders and workers alike. `elapsed` is called only when the noise
# has not stopped the render: seconds since the job started (a worker reads the job's
# start from Redis, a local render its own clock), or None when not known.
Elapsed = Callable[[], "float | None"]


def time_is_up(settings: RenderSettings, elapsed: Elapsed) -> bool:
    """Whether `time_limit` stops the render. It belongs to the noise target: a fixed spp
    renders every pass however long it takes."""
    if not settings.adaptive or settings.time_limit is None:
        return False
    seconds = elapsed()
    return seconds is not None and seconds >= settings.time_limit


def tile_stops(settings: RenderSettings, pass_index: int, rgba: np.ndarray,
               variance: np.ndarray | None, samples: int, elapsed: Elapsed) -> bool:
    """Whether a tile (per-tile stopping) gets no pass after `pass_index`."""
    return (not settings.adaptive or tile_finished(settings, pass_index, rgba, variance, samples)
            or time_is_up(settings, elapsed))


def image_stops(settings: RenderSettings, pass_index: int, acc: PassAccumulator, elapsed: Elapsed) -> bool:
    """Whether a lockstep job gets no pass after `pass_index`; `acc` holds passes 0..pass_index."""
    return image_finished(settings, pass_index, acc) or time_is_up(settings, elapsed)
