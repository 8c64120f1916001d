"""The embedded default: render every tile of an image in this process, no Redis or server.

Uses the same tile grid, pass schedule and pass combination (tessera.protocol) as the
farm; since pixels do not depend on tiling, the result is bit-identical to a farm render
with the same settings (in noise-target mode too, unless a time_limit cuts passes short).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from .protocol import (PassAccumulator, RenderSettings, TileRect, TileResult, combine_passes,
                       image_finished, pass_range, resolve_splats, tile_finished, tile_grid)


@dataclass
class LocalRenderResult:
    rgba: np.ndarray
    seconds: float
    samples: int
    passes: int = 0
    # The per-pixel noise estimate (images.VARIANCE_CHANNELS / SPP_CHANNEL): float32
    # (h, w, 3) per-sample variance and float32 (h, w) samples per pixel. None for the
    # splatting integrators (light, bdpt), whose splats carry no per-pixel variance.
    variance: np.ndarray | None = None
    spp: np.ndarray | None = None

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def render_tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int = 0,
                       deadline: float | None = None, integrator: str = "path") -> tuple[np.ndarray, int, int]:
    """One tile, pass after pass as the farm renders it, combined as the farm combines it.
    Returns (rgba, samples, passes). `deadline` (time.monotonic()) plays the time_limit."""
    mean, _, samples, passes = _tile_passes(scene, settings, rect, threads, deadline, integrator, False)
    return mean, samples, passes


def _tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int, deadline: float | None,
                 integrator: str, with_variance: bool):
    """render_tile_passes, also returning the tile's per-sample variance (requested from
    the renderer in fixed-spp mode too when `with_variance`; the mean does not change)."""
    results: list[TileResult] = []
    while True:
        p = len(results)
        sample_start, spp = pass_range(settings, p)
        kwargs = dict(width=settings.width, height=settings.height, spp=spp, seed=settings.seed,
                      max_depth=settings.max_depth, threads=threads, integrator=integrator)
        if settings.adaptive or with_variance:
            rgba, variance = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height,
                                               sample_start=sample_start, return_variance=True,
                                               **kwargs)
        else:
            rgba, variance = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height,
                                               **kwargs), None
        results.append(TileResult(rect.x0, rect.y0, rgba, p, sample_start, spp, variance))
        mean, var, samples = combine_passes(results)
        if not settings.adaptive or tile_finished(settings, p, mean, var, samples) or (
                deadline is not None and time.monotonic() >= deadline):
            return mean, var, samples, len(results)


def render_image(scene, settings: RenderSettings, threads: int = 0, progress: bool = True) -> LocalRenderResult:
    """Renders all tiles of `settings` with `scene` (a tessera_renderer.Scene)."""
    rgba = np.zeros((settings.height, settings.width, 4), dtype=np.float32)
    variance = np.zeros((settings.height, settings.width, 3), dtype=np.float32)
    spp = np.zeros((settings.height, settings.width), dtype=np.float32)
    tiles = tile_grid(settings.width, settings.height, settings.tile_size)
    integrator = scene.resolve_integrator(settings.integrator)
    if settings.lockstep or integrator in ("light", "bdpt"):
        return _render_lockstep(scene, settings, integrator, tiles, threads, progress)
    start = time.perf_counter()
    deadline = time.monotonic() + settings.time_limit if settings.time_limit else None
    samples = passes = 0
    with tqdm(total=settings.width * settings.height, unit="px", unit_scale=True, disable=not progress,
              desc="render", dynamic_ncols=True) as bar:
        for t in tiles:
            tile, var, n, p = _tile_passes(scene, settings, t, threads, deadline, integrator, True)
            rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = tile
            variance[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = var
            spp[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = n
            samples += n * t.width * t.height
            passes += p
            bar.update(t.width * t.height)
    seconds = time.perf_counter() - start
    return LocalRenderResult(rgba, seconds, samples, passes, variance, spp)


def _render_lockstep(scene, settings: RenderSettings, integrator: str, tiles, threads: int,
                     progress: bool) -> LocalRenderResult:
    """The whole image pass after pass, as the farm schedules lockstep jobs and splatting
    integrators: every tile's light paths splat into a full-frame integer buffer; after
    each pass the pass's whole-image estimate goes into a PassAccumulator and
    `image_finished` decides on another pass for every tile (fixed spp: one pass). Tiles'
    passes combine with combine_passes and all splats are normalised once by all light
    paths, exactly as the farm's merge does, so the images are equal bit for bit."""
    height, width = settings.height, settings.width
    splatting = integrator in ("light", "bdpt")
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
            sample_start, spp = pass_range(settings, p)
            bar.set_description(f"render ({integrator}, pass {p + 1})")
            bar.reset()
            pass_rgba = np.zeros((height, width, 4), dtype=np.float32)
            pass_splats = np.zeros((height, width, 3), dtype=np.int64) if splatting else None
            for t, results in zip(tiles, per_tile):
                out = scene.render_tile(t.x0, t.y0, t.width, t.height, width=width, height=height,
                                        spp=spp, seed=settings.seed, max_depth=settings.max_depth,
                                        threads=threads, sample_start=sample_start,
                                        return_variance=settings.adaptive, integrator=integrator,
                                        splats=pass_splats)
                rgba, variance = out if settings.adaptive else (out, None)
                results.append(TileResult(t.x0, t.y0, rgba, p, sample_start, spp, variance))
                pass_rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = rgba
                samples += t.width * t.height * spp
                bar.update(t.width * t.height)
            pass_paths = width * height * spp if splatting else 0  # one light path per sample
            if splatting:
                total_splats += pass_splats  # integers: exact, as the farm's sum of layers
                total_paths += pass_paths
            if not settings.adaptive:
                break
            # protocol.pass_image, from the same numbers the farm's barrier decodes.
            image = resolve_splats(pass_rgba, pass_splats, pass_paths) if splatting else pass_rgba
            acc = acc.add(image, spp)
            if image_finished(settings, p, acc) or (deadline is not None and time.monotonic() >= deadline):
                break
            p += 1
    rgba = np.zeros((height, width, 4), dtype=np.float32)
    for t, results in zip(tiles, per_tile):
        rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = combine_passes(results)[0]
    image = resolve_splats(rgba, total_splats, total_paths) if splatting else rgba
    return LocalRenderResult(image, time.perf_counter() - start, samples, p + 1)
