"""Rendering vcm iteration by iteration for the tests: each iteration runs its scene pass
(fresh light paths, the radius of the schedule) and renders its own sample range with that
product, so the per-iteration images are independent estimates whose spread gives the
standard error. And the merging tests' cached high-sample references."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

import render_cache
from tessera_base.film import resolve_splats
from tessera_renderer.film import new_splat_buffer


def render_iteration(scene, integrator: str, iteration: int, *, spp: int, seed: int, max_depth: int = 8,
                     params: dict | None = None, width: int | None = None, height: int | None = None,
                     threads: int = 2, crop: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Iteration `iteration` of `integrator` over the whole image, or over the pixels of
    `crop` = (x0, y0, w, h) only (the rest of the frame then holds just the splats of the
    crop's light paths): samples [iteration * spp, (iteration + 1) * spp), splats resolved
    by the light paths traced (one per pixel sample). vcm traces one batch of light paths
    an iteration (its `grow` = 0), as iterations of equal samples need."""
    w, h = width or scene.width, height or scene.height
    x0, y0, cw, ch = crop or (0, 0, w, h)
    if integrator == "vcm":  # iterations of equal samples: one batch of light paths each (vcm's grow = 0)
        params = {"grow": 0, **(params or {})}
    product = (scene.scene_pass(integrator, iteration, seed=seed, max_depth=max_depth, threads=threads,
                                integrator_params=params) if integrator == "vcm" else None)
    splats = new_splat_buffer(w, h)
    tile = scene.render_tile(x0, y0, cw, ch, width=w, height=h, spp=spp, seed=seed, max_depth=max_depth,
                             threads=threads, integrator=integrator, splats=splats, integrator_params=params,
                             scene_product=product, sample_start=iteration * spp)
    full = np.zeros((h, w, 4), np.float32)
    full[y0:y0 + ch, x0:x0 + cw] = tile
    return resolve_splats(full, splats, cw * ch * spp, scene.splat_exponent)


def iterations(scene, integrator: str, count: int, **kw) -> list[np.ndarray]:
    return [render_iteration(scene, integrator, k, **kw) for k in range(count)]


def mean_and_stderr(values) -> tuple[float, float]:
    v = np.asarray(values, dtype=np.float64)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v)))


def cached_halves(tag: str, scene, settings: str,
                  render: Callable[[int], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A reference as two independent renders, render(101) and render(202): their mean is
    the reference, half their difference its own noise. They take minutes, so they are
    cached across runs (tests/render_cache.py: keyed by the translated scene, `settings`
    and the build)."""
    out = render_cache.cached(tag, scene, {"settings": settings, "halves": [101, 202]},
                              lambda: {"a": render(101).astype(np.float64), "b": render(202).astype(np.float64)})
    return out["a"], out["b"]
