"""The embedded default: render every tile of an image in this process, no Redis or server.

Renders tile passes and assembles the image with the functions the farm uses
(tessera_base.film.render_tile_pass and assemble_image), on the same tile grid and pass
schedule (tessera_base.protocol); since pixels do not depend on tiling, the result is
bit-identical to a farm render with the same settings (in noise-target mode too, unless a
time_limit cuts passes short).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from tessera_base import images, integrators
from tessera_base.film import SplatSums, add_denoised, assemble_image, black_image_warning, pass_image, render_tile_pass, run_scene_pass
from tessera_base.convergence import PassAccumulator, combine_passes, image_stops, tile_stops
from tessera_base.protocol import RenderSettings, TileRect, TileResult, in_crop, job_tiles, pass_range


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
    # settings.denoise: why aovs has no "denoised" layer (film.add_denoised), else None.
    denoise_warning: str | None = None
    # film.black_image_warning: the image is black for its exposure, else None.
    black_warning: str | None = None

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def render_tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int = 0,
                       started: float | None = None, integrator: str | None = None,
                       aovs_out: dict | None = None) -> tuple[np.ndarray, int, int]:
    """One tile, pass after pass as the farm renders it, combined as the farm combines it.
    Returns (rgba, samples, passes). `started` (time.monotonic()) is when the time limit
    started counting.
    With settings.aovs, their combined tile layers go into `aovs_out` (name -> array)."""
    results = _tile_passes(scene, settings, rect, threads,
                           time.monotonic() if started is None else started, integrator)
    image = assemble_image(settings, {rect.index: results}, partial=True, with_aovs=aovs_out is not None,
                           tiles=[rect])
    if aovs_out is not None:
        window = (slice(rect.y0, rect.y0 + rect.height), slice(rect.x0, rect.x0 + rect.width))
        aovs_out.update({name: layer[window] for name, layer in image.aovs.items()})
    mean = image.rgba[rect.y0:rect.y0 + rect.height, rect.x0:rect.x0 + rect.width]
    return mean, sum(r.spp for r in results), len(results)


def _tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int,
                 started: float, integrator: str) -> list[TileResult]:
    """A tile's passes until it is finished, as the worker decides it (per-tile stopping;
    the per-sample variance is always rendered, the mean does not change)."""
    results: list[TileResult] = []
    while True:
        p = len(results)
        results.append(render_tile_pass(scene, settings, rect, p, integrator=integrator,
                                        threads=threads, variance=True)[0])
        if not settings.adaptive:
            return results
        mean, var, samples = combine_passes(results)
        if tile_stops(settings, p, mean, var, samples, lambda: time.monotonic() - started):
            return results


def render_image(scene, settings: RenderSettings, threads: int = 0, progress: bool = True,
                 variance: bool = True) -> LocalRenderResult:
    """Renders all tiles of `settings` with `scene` (a tessera_renderer.Scene). With
    `variance` (the default) the result carries its noise estimate; for the splatting
    integrators it comes from batches of the pass's own samples (convergence.VARIANCE_BATCHES),
    at 1-7 % of the render's time (docs/benchmarks/variance-batches.md).
    With settings.denoise, aovs gets the "denoised" layer (film.add_denoised) as the
    farm's merge adds it."""
    result = _render_image(scene, settings, threads, progress, variance)
    result.denoise_warning = add_denoised(settings, result.rgba, result.aovs)
    data = getattr(scene, "data", None)
    result.black_warning = black_image_warning(in_crop(settings, result.rgba), getattr(data, "brightest_light", None))
    return result


def _render_image(scene, settings: RenderSettings, threads: int, progress: bool,
                  variance: bool) -> LocalRenderResult:
    integrator = scene.resolve_integrator(settings.integrator)
    tiles = job_tiles(settings, integrator)  # with a crop, only the tiles that meet it
    if settings.lockstep or integrators.splats(integrator) or integrators.scene_passes(integrator):
        result = _render_lockstep(scene, settings, integrator, tiles, threads, progress, variance)
        result.integrator = integrator
        return result
    start = time.perf_counter()
    started = time.monotonic()
    per_tile: dict[int, list[TileResult]] = {}
    with tqdm(total=sum(t.width * t.height for t in tiles), unit="px", unit_scale=True, disable=not progress,
              desc="render", dynamic_ncols=True) as bar:
        for t in tiles:
            per_tile[t.index] = _tile_passes(scene, settings, t, threads, started, integrator)
            bar.update(t.width * t.height)
    image = assemble_image(settings, per_tile, with_aovs=True, tiles=tiles)
    samples = sum(r.spp * t.width * t.height for t in tiles for r in per_tile[t.index])
    passes = sum(len(rs) for rs in per_tile.values())
    return LocalRenderResult(image.rgba, time.perf_counter() - start, samples, passes, image.variance,
                             image.spp, image.aovs, variance_kind=images.VARIANCE_PER_SAMPLE,
                             integrator=integrator)


def _render_lockstep(scene, settings: RenderSettings, integrator: str, tiles, threads: int,
                     progress: bool, want_variance: bool) -> LocalRenderResult:
    """The whole image pass after pass, as the farm schedules lockstep jobs and splatting
    integrators: every tile's splats are folded into the job's SplatSums as they come;
    after each pass the pass's whole-image estimate goes into a PassAccumulator and
    `image_finished` decides on another pass for every tile (fixed spp: one pass, or for
    a progressive integrator all of pass_range's). The
    image is assembled from the same results and sums as the farm's merge assembles it."""
    height, width = settings.height, settings.width
    splatting = integrators.splats(integrator)
    scene_passes = integrators.scene_passes(integrator)
    batches = want_variance and splatting
    per_tile: dict[int, list[TileResult]] = {t.index: [] for t in tiles}
    sums = SplatSums(width, height)
    samples = 0
    acc = PassAccumulator()
    start = time.perf_counter()
    started = time.monotonic()
    p = 0
    with tqdm(total=sum(t.width * t.height for t in tiles), unit="px", unit_scale=True, disable=not progress,
              desc=f"render ({integrator})", dynamic_ncols=True) as bar:
        while True:
            spp = pass_range(settings, p)[1]
            bar.set_description(f"render ({integrator}, pass {p + 1})")
            bar.reset()
            this_pass = []
            # Iteration p's scene-wide phase, once, before its tiles (as the farm's scene task).
            product = (run_scene_pass(scene, settings, p, integrator=integrator, threads=threads)
                       if scene_passes else None)
            for t in tiles:
                result, _ = render_tile_pass(scene, settings, t, p, integrator=integrator,
                                             threads=threads, variance=settings.adaptive,
                                             batches=batches, scene_product=product, into=sums)
                per_tile[t.index].append(result)
                this_pass.append(result)
                samples += t.width * t.height * spp
                bar.update(t.width * t.height)
            if pass_range(settings, p + 1) is None:
                break
            acc = acc.add(in_crop(settings, pass_image(width, height, this_pass, sums)), spp)
            if image_stops(settings, p, acc, lambda: time.monotonic() - started):
                break
            p += 1
    image = assemble_image(settings, per_tile, sums, with_aovs=True, tiles=tiles)
    result = LocalRenderResult(image.rgba, time.perf_counter() - start, samples, p + 1, aovs=image.aovs)
    if not want_variance:
        return result
    if splatting:
        if image.batch_variance is not None:
            result.variance = image.batch_variance[0]
            result.variance_kind = images.batch_means_kind(image.batch_variance[1])
            result.spp = image.spp
    elif image.variance is not None:  # per-sample variance is valid without splats
        result.variance, result.variance_kind = image.variance, images.VARIANCE_PER_SAMPLE
        result.spp = image.spp
    return result
