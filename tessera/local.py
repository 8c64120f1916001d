"""The embedded default: render every tile of an image in this process, no Redis or server.

Uses the same tile grid, pass schedule and pass combination (tessera.protocol) as the
farm; since pixels do not depend on tiling, the result is bit-identical to a farm render
with the same settings (in noise-target mode too, unless a time_limit cuts passes short).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from . import images, integrators

from .protocol import (AOV_CHANNELS, BatchMeans, PassAccumulator, RenderSettings, TileRect, TileResult,
                       batch_ranges, combine_aovs, combine_passes, image_finished, new_aov_frame, pass_range,
                       resolve_splats, tile_finished, tile_grid)


@dataclass
class LocalRenderResult:
    rgba: np.ndarray
    seconds: float
    samples: int
    passes: int = 0
    # The per-pixel noise estimate (images.VARIANCE_CHANNELS / SPP_CHANNEL): float32
    # (h, w, 3) variance and float32 (h, w) samples per pixel. `variance_kind` says what
    # the variance is (images.VARIANCE_PER_SAMPLE: of one sample, for the integrators
    # without splats; images.batch_means_kind(K): of the pixel's mean, from K independent
    # batches, for light and bdpt). None when not computed.
    variance: np.ndarray | None = None
    spp: np.ndarray | None = None
    aovs: dict[str, np.ndarray] = field(default_factory=dict)  # settings.aovs, full frame
    variance_kind: str | None = None  # see `variance`
    integrator: str = ""  # the integrator that rendered it (`auto` resolved)

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def render_tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int = 0,
                       deadline: float | None = None, integrator: str | None = None,
                       aovs_out: dict | None = None) -> tuple[np.ndarray, int, int]:
    """One tile, pass after pass as the farm renders it, combined as the farm combines it.
    Returns (rgba, samples, passes). `deadline` (time.monotonic()) plays the time_limit.
    With settings.aovs, their combined tile layers go into `aovs_out` (name -> array).
    `integrator` defaults to the registry's first."""
    mean, _, samples, passes = _tile_passes(scene, settings, rect, threads, deadline,
                                            integrator or integrators.default(), False, aovs_out)
    return mean, samples, passes


def _render_pass(scene, settings: RenderSettings, rect: TileRect, p: int, threads: int, integrator: str,
                 want_variance: bool, splats: np.ndarray | None = None) -> TileResult:
    """Pass p of one tile as a worker renders it: RGBA, variance and AOVs if asked for."""
    sample_start, spp = pass_range(settings, p)
    core_aovs = [a for a in settings.aovs if a in AOV_CHANNELS]
    want_variance = want_variance or "variance" in settings.aovs
    out = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height, width=settings.width,
                            height=settings.height, spp=spp, seed=settings.seed,
                            max_depth=settings.max_depth, threads=threads, sample_start=sample_start,
                            return_variance=want_variance, integrator=integrator, splats=splats,
                            aovs=core_aovs)
    layers, variance = None, None
    if core_aovs:
        rgba, layers = out
        variance = layers.pop("variance", None)
    elif want_variance:
        rgba, variance = out
    else:
        rgba = out
    return TileResult(rect.x0, rect.y0, rgba, p, sample_start, spp, variance, aovs=layers)


def _tile_aovs(settings: RenderSettings, results: list[TileResult], variance) -> dict:
    layers = combine_aovs(results) if any(a in AOV_CHANNELS for a in settings.aovs) else {}
    if "variance" in settings.aovs:
        layers["variance"] = variance
    return layers


def _tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int, deadline: float | None,
                 integrator: str, with_variance: bool, aovs_out: dict | None = None):
    """render_tile_passes, also returning the tile's per-sample variance (requested from
    the renderer in fixed-spp mode too when `with_variance`; the mean does not change)."""
    results: list[TileResult] = []
    while True:
        p = len(results)
        results.append(_render_pass(scene, settings, rect, p, threads, integrator,
                                    settings.adaptive or with_variance))
        mean, var, samples = combine_passes(results)
        if not settings.adaptive or tile_finished(settings, p, mean, var, samples) or (
                deadline is not None and time.monotonic() >= deadline):
            if aovs_out is not None:
                aovs_out.update(_tile_aovs(settings, results, var))
            return mean, var, samples, len(results)


def render_image(scene, settings: RenderSettings, threads: int = 0, progress: bool = True,
                 variance: bool = True) -> LocalRenderResult:
    """Renders all tiles of `settings` with `scene` (a tessera_renderer.Scene). With
    `variance` (the default) the result carries its noise estimate; for light and bdpt
    that renders every sample a second time, in batches (protocol.VARIANCE_BATCHES)."""
    want_variance = variance
    rgba = np.zeros((settings.height, settings.width, 4), dtype=np.float32)
    variance = np.zeros((settings.height, settings.width, 3), dtype=np.float32)
    spp = np.zeros((settings.height, settings.width), dtype=np.float32)
    tiles = tile_grid(settings.width, settings.height, settings.tile_size)
    integrator = scene.resolve_integrator(settings.integrator)
    if settings.lockstep or integrators.splats(integrator):
        result = _render_lockstep(scene, settings, integrator, tiles, threads, progress)
        if want_variance and integrators.splats(integrator):
            started = time.perf_counter()
            result.variance, result.variance_kind = batch_variance(scene, settings, integrator, tiles,
                                                                   threads, result.passes)
            result.seconds += time.perf_counter() - started
            if "variance" in result.aovs:  # the farm's merge replaces it the same way
                result.aovs["variance"] = (result.variance if result.variance is not None
                                           else result.aovs["variance"])
            result.spp = None if result.variance is None else np.full((settings.height, settings.width), result.samples
                                 / (settings.width * settings.height), np.float32)
        elif not want_variance:
            result.variance = result.spp = result.variance_kind = None
        result.integrator = integrator
        return result
    start = time.perf_counter()
    deadline = time.monotonic() + settings.time_limit if settings.time_limit else None
    samples = passes = 0
    aovs = new_aov_frame(settings)
    with tqdm(total=settings.width * settings.height, unit="px", unit_scale=True, disable=not progress,
              desc="render", dynamic_ncols=True) as bar:
        for t in tiles:
            layers: dict = {}
            tile, var, n, p = _tile_passes(scene, settings, t, threads, deadline, integrator, True, layers)
            rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = tile
            variance[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = var
            spp[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = n
            paste_aovs(aovs, layers, t)
            samples += n * t.width * t.height
            passes += p
            bar.update(t.width * t.height)
    seconds = time.perf_counter() - start
    return LocalRenderResult(rgba, seconds, samples, passes, variance, spp, aovs,
                             variance_kind=images.VARIANCE_PER_SAMPLE, integrator=integrator)


def _samples_per_pixel(settings: RenderSettings, passes: int) -> np.ndarray:
    """Samples of every pixel of a lockstep render of `passes` passes (all tiles alike)."""
    n = sum(pass_range(settings, p)[1] for p in range(passes))
    return np.full((settings.height, settings.width), n, np.float32)


def batch_variance(scene, settings: RenderSettings, integrator: str, tiles, threads: int,
                   passes: int) -> tuple[np.ndarray | None, str | None]:
    """The variance of every pixel's mean for a splatting integrator, from batch means
    (protocol.VARIANCE_BATCHES): each pass's samples again as independent sub-ranges, each
    a whole image (camera part + its own splats over its own light paths). Returns the
    float32 (h, w, 3) variance and its images.batch_means_kind (None, None with one
    sample, which cannot estimate its own variance)."""
    height, width = settings.height, settings.width
    acc = BatchMeans()
    for p in range(passes):
        for start, n in batch_ranges(*pass_range(settings, p)):
            rgb = np.zeros((height, width, 4), np.float32)
            splats = np.zeros((height, width, 3), np.int64)
            for t in tiles:
                out = scene.render_tile(t.x0, t.y0, t.width, t.height, width=width, height=height,
                                        spp=n, seed=settings.seed, max_depth=settings.max_depth,
                                        threads=threads, sample_start=start, integrator=integrator,
                                        splats=splats)
                rgb[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = out
            image = resolve_splats(rgb, splats, width * height * n, scene.splat_exponent)
            acc.add(image[..., :3], n)
    var = acc.variance_of_mean()  # None from one sample: no estimate
    return var, None if var is None else images.batch_means_kind(acc.batches)


def paste_aovs(frame: dict[str, np.ndarray], layers: dict[str, np.ndarray], rect: TileRect) -> None:
    """Copies a tile's AOV layers into the full-frame buffers of new_aov_frame."""
    for name, buf in frame.items():
        if name not in layers or layers[name] is None:
            raise ValueError(f"tile {rect.index} has no {name} AOV")
        buf[rect.y0:rect.y0 + rect.height, rect.x0:rect.x0 + rect.width] = \
            np.asarray(layers[name], np.float32).reshape(rect.height, rect.width, -1)


def _render_lockstep(scene, settings: RenderSettings, integrator: str, tiles, threads: int,
                     progress: bool) -> LocalRenderResult:
    """The whole image pass after pass, as the farm schedules lockstep jobs and splatting
    integrators: every tile's light paths splat into a full-frame integer buffer; after
    each pass the pass's whole-image estimate goes into a PassAccumulator and
    `image_finished` decides on another pass for every tile (fixed spp: one pass). Tiles'
    passes combine with combine_passes and all splats are normalised once by all light
    paths, exactly as the farm's merge does, so the images are equal bit for bit."""
    height, width = settings.height, settings.width
    splatting = integrators.splats(integrator)
    per_tile: list[list[TileResult]] = [[] for _ in tiles]
    total_splats = np.zeros((height, width, 3), dtype=np.int64) if splatting else None
    total_paths = samples = 0
    acc = PassAccumulator()
    start = time.perf_counter()
    deadline = time.monotonic() + settings.time_limit if settings.time_limit else None
    p = 0
    with tqdm(total=width * height, unit="px", unit_scale=True, disable=not progress,
              desc=f"render ({integrator})", dynamic_ncols=True) as bar:
        while True:
            spp = pass_range(settings, p)[1]
            bar.set_description(f"render ({integrator}, pass {p + 1})")
            bar.reset()
            pass_rgba = np.zeros((height, width, 4), dtype=np.float32)
            pass_splats = np.zeros((height, width, 3), dtype=np.int64) if splatting else None
            for t, results in zip(tiles, per_tile):
                result = _render_pass(scene, settings, t, p, threads, integrator, settings.adaptive,
                                      pass_splats)
                results.append(result)
                pass_rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = result.rgba
                samples += t.width * t.height * spp
                bar.update(t.width * t.height)
            pass_paths = width * height * spp if splatting else 0  # one light path per sample
            if splatting:
                total_splats += pass_splats  # integers: exact, as the farm's sum of layers
                total_paths += pass_paths
            if not settings.adaptive:
                break
            # protocol.pass_image, from the same numbers the farm's barrier decodes.
            image = resolve_splats(pass_rgba, pass_splats, pass_paths, scene.splat_exponent) if splatting else pass_rgba
            acc = acc.add(image, spp)
            if image_finished(settings, p, acc) or (deadline is not None and time.monotonic() >= deadline):
                break
            p += 1
    rgba = np.zeros((height, width, 4), dtype=np.float32)
    variance: np.ndarray | None = np.zeros((height, width, 3), dtype=np.float32)
    aovs = new_aov_frame(settings)
    for t, results in zip(tiles, per_tile):
        mean, var, _ = combine_passes(results)
        rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = mean
        if var is None:
            variance = None
        elif variance is not None:
            variance[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = var
        paste_aovs(aovs, _tile_aovs(settings, results, var), t)
    image = resolve_splats(rgba, total_splats, total_paths, scene.splat_exponent) if splatting else rgba
    result = LocalRenderResult(image, time.perf_counter() - start, samples, p + 1, aovs=aovs)
    if not splatting and variance is not None:  # per-sample variance is valid without splats
        result.variance, result.variance_kind = variance, images.VARIANCE_PER_SAMPLE
        result.spp = _samples_per_pixel(settings, p + 1)
    return result
