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

from .protocol import (AOV_CHANNELS, new_aov_frame, RenderSettings, TileRect, TileResult, combine_aovs, combine_passes,
                       pass_range, resolve_splats, tile_finished, tile_grid)


@dataclass
class LocalRenderResult:
    rgba: np.ndarray
    seconds: float
    samples: int
    passes: int = 0
    aovs: dict[str, np.ndarray] = field(default_factory=dict)  # settings.aovs, full frame

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def render_tile_passes(scene, settings: RenderSettings, rect: TileRect, threads: int = 0,
                       deadline: float | None = None, integrator: str = "path",
                       aovs_out: dict | None = None) -> tuple[np.ndarray, int, int]:
    """One tile, pass after pass as the farm renders it, combined as the farm combines it.
    Returns (rgba, samples, passes). `deadline` (time.monotonic()) plays the time_limit.
    With settings.aovs, their combined tile layers go into `aovs_out` (name -> array)."""
    results: list[TileResult] = []
    want_variance = settings.adaptive or "variance" in settings.aovs
    core_aovs = [a for a in settings.aovs if a in AOV_CHANNELS]
    while True:
        p = len(results)
        sample_start, spp = pass_range(settings, p)
        kwargs = dict(width=settings.width, height=settings.height, spp=spp, seed=settings.seed,
                      max_depth=settings.max_depth, threads=threads, integrator=integrator)
        layers = None
        if want_variance or core_aovs:
            rgba, layers = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height,
                                             sample_start=sample_start, aovs=core_aovs,
                                             return_variance=want_variance, **kwargs)
            if not core_aovs and not isinstance(layers, dict):
                layers = {"variance": layers}
            variance = layers.pop("variance", None)
        else:
            rgba, variance = scene.render_tile(rect.x0, rect.y0, rect.width, rect.height,
                                               **kwargs), None
        results.append(TileResult(rect.x0, rect.y0, rgba, p, sample_start, spp, variance, aovs=layers))
        mean, var, samples = combine_passes(results)
        if not settings.adaptive or tile_finished(settings, p, mean, var, samples) or (
                deadline is not None and time.monotonic() >= deadline):
            if aovs_out is not None:
                aovs_out.update(combine_aovs(results) if core_aovs else {})
                if "variance" in settings.aovs:
                    aovs_out["variance"] = var
            return mean, samples, len(results)


def render_image(scene, settings: RenderSettings, threads: int = 0, progress: bool = True) -> LocalRenderResult:
    """Renders all tiles of `settings` with `scene` (a tessera_renderer.Scene)."""
    rgba = np.zeros((settings.height, settings.width, 4), dtype=np.float32)
    tiles = tile_grid(settings.width, settings.height, settings.tile_size)
    integrator = scene.resolve_integrator(settings.integrator)
    if integrator in ("light", "bdpt"):
        return _render_splatting(scene, settings, integrator, tiles, threads, progress)
    start = time.perf_counter()
    deadline = time.monotonic() + settings.time_limit if settings.time_limit else None
    samples = passes = 0
    aovs = new_aov_frame(settings)
    with tqdm(total=settings.width * settings.height, unit="px", unit_scale=True, disable=not progress,
              desc="render", dynamic_ncols=True) as bar:
        for t in tiles:
            layers: dict = {}
            tile, n, p = render_tile_passes(scene, settings, t, threads, deadline, integrator, layers)
            rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = tile
            paste_aovs(aovs, layers, t)
            samples += n * t.width * t.height
            passes += p
            bar.update(t.width * t.height)
    seconds = time.perf_counter() - start
    return LocalRenderResult(rgba, seconds, samples, passes, aovs)


def paste_aovs(frame: dict[str, np.ndarray], layers: dict[str, np.ndarray], rect: TileRect) -> None:
    """Copies a tile's AOV layers into the full-frame buffers of new_aov_frame."""
    for name, buf in frame.items():
        if name not in layers or layers[name] is None:
            raise ValueError(f"tile {rect.index} has no {name} AOV")
        buf[rect.y0:rect.y0 + rect.height, rect.x0:rect.x0 + rect.width] = \
            np.asarray(layers[name], np.float32).reshape(rect.height, rect.width, -1)


def _render_splatting(scene, settings: RenderSettings, integrator: str, tiles, threads: int,
                      progress: bool) -> LocalRenderResult:
    """light / bdpt: one pass per tile, every tile's light paths splatting into one
    full-frame buffer; the sum is exact, so this equals the farm's merge bit for bit."""
    rgba = np.zeros((settings.height, settings.width, 4), dtype=np.float32)
    splats = np.zeros((settings.height, settings.width, 3), dtype=np.int64)
    light_paths = 0
    aovs = new_aov_frame(settings)
    start = time.perf_counter()
    with tqdm(total=settings.width * settings.height, unit="px", unit_scale=True, disable=not progress,
              desc=f"render ({integrator})", dynamic_ncols=True) as bar:
        for t in tiles:
            out = scene.render_tile(
                t.x0, t.y0, t.width, t.height, width=settings.width, height=settings.height, spp=settings.spp,
                seed=settings.seed, max_depth=settings.max_depth, threads=threads, integrator=integrator,
                splats=splats, aovs=settings.aovs)
            tile, layers = out if settings.aovs else (out, {})
            rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = tile
            paste_aovs(aovs, layers, t)
            light_paths += t.width * t.height * settings.spp
            bar.update(t.width * t.height)
    seconds = time.perf_counter() - start
    image = resolve_splats(rgba, splats, light_paths)
    return LocalRenderResult(image, seconds, settings.width * settings.height * settings.spp, len(tiles), aovs)
