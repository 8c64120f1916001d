"""The embedded default: render every tile of an image in this process, no Redis or server.

Uses the same tile grid as the farm; since pixels do not depend on tiling, the result is
bit-identical to a farm render with the same settings.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from .protocol import RenderSettings, tile_grid


@dataclass
class LocalRenderResult:
    rgba: np.ndarray
    seconds: float
    samples: int

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def render_image(scene, settings: RenderSettings, threads: int = 0, progress: bool = True) -> LocalRenderResult:
    """Renders all tiles of `settings` with `scene` (a tessera_renderer.Scene)."""
    rgba = np.zeros((settings.height, settings.width, 4), dtype=np.float32)
    tiles = tile_grid(settings.width, settings.height, settings.tile_size)
    start = time.perf_counter()
    with tqdm(total=settings.width * settings.height, unit="px", unit_scale=True, disable=not progress,
              desc="render", dynamic_ncols=True) as bar:
        for t in tiles:
            rgba[t.y0:t.y0 + t.height, t.x0:t.x0 + t.width] = scene.render_tile(
                t.x0, t.y0, t.width, t.height, width=settings.width, height=settings.height,
                spp=settings.spp, seed=settings.seed, max_depth=settings.max_depth, threads=threads)
            bar.update(t.width * t.height)
    seconds = time.perf_counter() - start
    return LocalRenderResult(rgba, seconds, settings.width * settings.height * settings.spp)
