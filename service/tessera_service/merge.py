"""Merging a finished job's tiles into one image, and encoding it as EXR and PNG."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from tessera import images
from tessera.protocol import JobSpec, decode_tile, tile_grid


class MergeError(Exception):
    """The stored tiles do not form the job's image (missing, misplaced or corrupt)."""


def merge_tiles(spec: JobSpec, tiles: dict[bytes | str, bytes]) -> np.ndarray:
    """Pastes every tile into a full float RGBA image; returns it as (h, w, 4) float32."""
    s = spec.settings
    grid = tile_grid(s.width, s.height, s.tile_size)
    full = oiio.ImageBuf(oiio.ImageSpec(s.width, s.height, 4, oiio.FLOAT))
    seen = set()
    for key, data in tiles.items():
        index = int(key)
        if not 0 <= index < len(grid):
            raise MergeError(f"tile index {index} is outside the job's grid of {len(grid)}")
        try:
            x0, y0, rgba = decode_tile(data)
        except ValueError as e:
            raise MergeError(f"tile {index}: {e}") from e
        rect = grid[index]
        if (x0, y0, rgba.shape[1], rgba.shape[0]) != (rect.x0, rect.y0, rect.width, rect.height):
            raise MergeError(f"tile {index} covers ({x0}, {y0}, {rgba.shape[1]}x{rgba.shape[0]}), "
                             f"expected ({rect.x0}, {rect.y0}, {rect.width}x{rect.height})")
        tile = oiio.ImageBuf(oiio.ImageSpec(rect.width, rect.height, 4, oiio.FLOAT))
        if not tile.set_pixels(oiio.ROI(), np.ascontiguousarray(rgba)):
            raise MergeError(f"tile {index}: {tile.geterror()}")
        if not oiio.ImageBufAlgo.paste(full, rect.x0, rect.y0, 0, 0, tile):
            raise MergeError(f"tile {index}: {full.geterror()}")
        seen.add(index)
    if len(seen) != len(grid):
        missing = sorted(set(range(len(grid))) - seen)
        raise MergeError(f"{len(missing)} of {len(grid)} tiles are missing (first: {missing[:5]})")
    return np.asarray(full.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(s.height, s.width, 4)


def encode_images(rgba: np.ndarray, spec: JobSpec) -> tuple[bytes, bytes]:
    """The image as float EXR bytes (with the same header attributes as a local render)
    and as a tonemapped sRGB PNG preview."""
    with tempfile.TemporaryDirectory(prefix="tessera-merge-") as tmp:
        exr, png = Path(tmp, "image.exr"), Path(tmp, "preview.png")
        images.write_exr(exr, rgba, images.render_metadata(spec.settings.spp, spec.settings.seed,
                                                           spec.scene_name))
        images.write_png_preview(png, rgba)
        return exr.read_bytes(), png.read_bytes()
