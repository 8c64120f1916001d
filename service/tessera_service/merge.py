"""Merging a finished job's tiles into one image, and encoding it as EXR and PNG."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from tessera import images
from tessera.protocol import (JobSpec, TileResult, add_splats, combine_aovs, combine_passes, decode_tile,
                              batch_variance, new_aov_frame, resolve_splats, splat_exponent_of,
                              tile_grid)


class MergeError(Exception):
    """The stored tiles do not form the job's image (missing, misplaced or corrupt)."""


def merge_tiles(spec: JobSpec, tiles: dict[bytes | str, bytes], *, partial: bool = False,
                with_aovs: bool = False):
    """Combines each tile's passes (protocol.combine_passes, as the local render does) and
    pastes the tiles into a full float RGBA image; returns it as (h, w, 4) float32. With
    `partial`, missing tiles stay black (a preview of a running job). With `with_aovs`,
    returns (rgba, aovs): the job's AOVs (settings.aovs) merged like the local render's
    (protocol.combine_aovs), as full-frame float32 (h, w, c) layers."""
    s = spec.settings
    grid = tile_grid(s.width, s.height, s.tile_size)
    passes: dict[int, list[TileResult]] = {}
    for key, data in tiles.items():
        field = key.decode() if isinstance(key, bytes) else str(key)
        try:
            index, pass_index = (int(v) for v in field.split(":"))
        except ValueError:
            raise MergeError(f"tile result field {field!r} is not 'tile:pass'") from None
        if not 0 <= index < len(grid):
            raise MergeError(f"tile index {index} is outside the job's grid of {len(grid)}")
        try:
            result = decode_tile(data)
        except ValueError as e:
            raise MergeError(f"tile {index} pass {pass_index}: {e}") from e
        rect = grid[index]
        h, w = result.rgba.shape[:2]
        if (result.x0, result.y0, w, h) != (rect.x0, rect.y0, rect.width, rect.height):
            raise MergeError(f"tile {index} covers ({result.x0}, {result.y0}, {w}x{h}), "
                             f"expected ({rect.x0}, {rect.y0}, {rect.width}x{rect.height})")
        if result.pass_index != pass_index:
            raise MergeError(f"tile {index}: result of pass {result.pass_index} stored as "
                             f"pass {pass_index}")
        passes.setdefault(index, []).append(result)
    if not partial and len(passes) != len(grid):
        missing = sorted(set(range(len(grid))) - set(passes))
        raise MergeError(f"{len(missing)} of {len(grid)} tiles are missing (first: {missing[:5]})")
    full = np.zeros((s.height, s.width, 4), dtype=np.float32)
    aovs = new_aov_frame(s) if with_aovs else {}
    # Light-tracing splats from every result, summed exactly (integers) and normalised once
    # by the light paths of all results (protocol.resolve_splats).
    splats = None
    light_paths = 0
    for results in passes.values():
        for r in results:
            if r.splat is not None:
                if splats is None:
                    splats = np.zeros((s.height, s.width, 3), dtype=np.int64)
                add_splats(splats, r.splat_rect, r.splat)
                light_paths += r.light_paths
    for index, results in passes.items():
        rect = grid[index]
        results.sort(key=lambda r: r.pass_index)
        if [r.pass_index for r in results] != list(range(len(results))):
            if not partial:
                raise MergeError(f"tile {index} is missing a pass")
            results = [r for i, r in enumerate(results) if r.pass_index == i]
            if not results:
                continue
        try:
            rgba, variance, _ = combine_passes(results)
            layers = combine_aovs(results) if aovs else {}
        except ValueError as e:
            raise MergeError(f"tile {index}: {e}") from e
        full[rect.y0:rect.y0 + rect.height, rect.x0:rect.x0 + rect.width] = rgba
        if variance is not None:
            layers["variance"] = variance
        for name, buf in aovs.items():
            if layers.get(name) is None:
                raise MergeError(f"tile {index} has no {name} AOV (rendered by a worker without AOVs?)")
            buf[rect.y0:rect.y0 + rect.height, rect.x0:rect.x0 + rect.width] = \
                np.asarray(layers[name], np.float32).reshape(rect.height, rect.width, -1)
    if splats is not None:
        try:
            exponent = splat_exponent_of([r for results in passes.values() for r in results])
        except ValueError as e:
            raise MergeError(str(e)) from e
        full = resolve_splats(full, splats, light_paths, exponent)
    if "variance" in aovs:
        aovs = MergedLayers(aovs)
        if splats is None:
            aovs.variance_kind = images.VARIANCE_PER_SAMPLE
        elif not partial:
            # light and bdpt: the per-sample layer misses the splats; the batches replace it.
            try:
                estimate = batch_variance(s.width, s.height, [r for rs in passes.values() for r in rs])
            except ValueError as e:
                raise MergeError(str(e)) from e
            if estimate is not None:
                aovs["variance"], aovs.variance_kind = estimate[0], images.batch_means_kind(estimate[1])
    image = full
    return (image, aovs) if with_aovs else image


class MergedLayers(dict):
    """merge_tiles' AOV layers, with what their variance layer means (images'
    VARIANCE_ATTRIBUTE kinds; None when it is not a valid estimate, e.g. light or bdpt
    results rendered without batches)."""
    variance_kind: str | None = None


def farm_variance_kind(settings, aovs: dict | None) -> str | None:
    """What a merged variance layer means (MergedLayers.variance_kind)."""
    if not aovs or "variance" not in aovs:
        return None
    return getattr(aovs, "variance_kind", None)


def encode_image(rgba: np.ndarray, spec: JobSpec, fmt: str, aovs: dict[str, np.ndarray] | None = None) -> bytes:
    """The image as float EXR bytes (with the same header attributes and AOV layers as a
    local render) or as a tonemapped sRGB PNG preview (colour only)."""
    with tempfile.TemporaryDirectory(prefix=f"tessera-merge-{os.getpid()}-") as tmp:
        path = Path(tmp, f"image.{fmt}")
        if fmt == "exr":
            s = spec.settings
            images.write_exr(path, rgba, images.render_metadata(
                s.max_spp if s.adaptive else s.spp, s.seed, spec.scene_name, s.integrator,
                farm_variance_kind(s, aovs)), aovs=aovs)
        else:
            images.write_png_preview(path, rgba)
        return path.read_bytes()
