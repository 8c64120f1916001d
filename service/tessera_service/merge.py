"""Merging a finished job's tiles into one image, and encoding it as EXR and PNG."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from tessera_base import images
from tessera_base.film import SplatSums, add_denoised, assemble_image
from tessera_base.protocol import JobSpec, TileResult, decode_tile, in_crop, job_tiles


class MergeError(Exception):
    """The stored tiles do not form the job's image (missing, misplaced or corrupt)."""


def merge_tiles(spec: JobSpec, tiles: dict[bytes | str, bytes], *, partial: bool = False,
                with_aovs: bool = False, splats: dict[bytes | str, bytes] | None = None):
    """Decodes and checks the stored results of a job and assembles them as the local
    render does (tessera_base.film.assemble_image); returns the (h, w, 4) float32 image. `splats`
    is the job's splat sums hash (redis_schema.job_splats_key). With `partial`, missing
    tiles stay black (a preview of a running job). With `with_aovs`, returns (rgba, aovs):
    the job's AOVs (settings.aovs) as full-frame float32 (h, w, c) layers, and for a job
    with settings.denoise the "denoised" layer (tessera_base.film.add_denoised, as the local
    render adds it; MergedLayers.denoise_warning says why it is missing)."""
    s = spec.settings
    passes = _decode_passes(spec, tiles)
    try:
        sums = SplatSums.from_fields(s.width, s.height, splats or {})
        image = assemble_image(s, passes, sums, partial=partial, with_aovs=with_aovs)
    except ValueError as e:
        raise MergeError(str(e)) from e
    if not with_aovs:
        return image.rgba
    aovs = MergedLayers(image.aovs)
    aovs.variance_kind = image.variance_kind
    aovs.denoise_warning = add_denoised(s, image.rgba, aovs)
    return image.rgba, aovs


def reached_noise(spec: JobSpec, tiles: dict[bytes | str, bytes],
                  splats: dict[bytes | str, bytes] | None = None) -> float | None:
    """The relative noise a finished job's image reached, as the EXR's tessera:reached_error
    measures it, from the tiles' own noise estimate whether or not the job asked for the
    variance AOV (per-sample variance; for splatting integrators the batch estimate, which
    tiles carry only with that AOV: None without it)."""
    from tessera_base.exr_header import reached_error

    s = spec.settings
    try:
        image = assemble_image(s, _decode_passes(spec, tiles),
                               SplatSums.from_fields(s.width, s.height, splats or {}))
    except ValueError as e:
        raise MergeError(str(e)) from e
    if image.splatting:
        if image.batch_variance is None:
            return None
        return reached_error(in_crop(s, image.rgba), in_crop(s, image.batch_variance[0]), in_crop(s, image.spp),
                             images.batch_means_kind(image.batch_variance[1]))
    return reached_error(in_crop(s, image.rgba), in_crop(s, image.variance), in_crop(s, image.spp),
                         images.VARIANCE_PER_SAMPLE)


def _decode_passes(spec: JobSpec, tiles: dict[bytes | str, bytes]) -> dict[int, list[TileResult]]:
    s = spec.settings
    grid = {t.index: t for t in job_tiles(s)}
    passes: dict[int, list[TileResult]] = {}
    for key, data in tiles.items():
        field = key.decode() if isinstance(key, bytes) else str(key)
        try:
            index, pass_index = (int(v) for v in field.split(":"))
        except ValueError:
            raise MergeError(f"tile result field {field!r} is not 'tile:pass'") from None
        if index not in grid:
            raise MergeError(f"tile index {index} is not one of the job's {len(grid)} tiles")
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
    return passes


class MergedLayers(dict):
    """merge_tiles' AOV layers, with what their variance layer means (images'
    VARIANCE_ATTRIBUTE kinds; None when it is not a valid estimate, e.g. light or bdpt
    results rendered without batches)."""
    variance_kind: str | None = None
    denoise_warning: str | None = None


def farm_variance_kind(settings, aovs: dict | None) -> str | None:
    """What a merged variance layer means (MergedLayers.variance_kind)."""
    if not aovs or "variance" not in aovs:
        return None
    return getattr(aovs, "variance_kind", None)


def denoised_png(aovs: dict[str, np.ndarray], spec: JobSpec) -> bytes:
    """The denoised preview PNG of merge_tiles' layers; MergeError when there is none."""
    from tessera_base.denoise import DENOISED_LAYER

    if DENOISED_LAYER not in aovs:
        raise MergeError(getattr(aovs, "denoise_warning", None)
                         or "the job was not submitted with denoise=true")
    return encode_image(aovs[DENOISED_LAYER], spec, "png")


def read_denoised(exr: bytes) -> np.ndarray | None:
    """The denoised RGB layer of an EXR's bytes (encode_image's), None without one."""
    with tempfile.TemporaryDirectory(prefix=f"tessera-merge-{os.getpid()}-") as tmp:
        path = Path(tmp, "image.exr")
        path.write_bytes(exr)
        return images.read_exr_aovs(path).get("denoised")


def encode_image(rgba: np.ndarray, spec: JobSpec, fmt: str, aovs: dict[str, np.ndarray] | None = None) -> bytes:
    """The image as float EXR bytes (with the same header attributes and AOV layers as a
    local render) or as a tonemapped sRGB PNG preview (colour only)."""
    with tempfile.TemporaryDirectory(prefix=f"tessera-merge-{os.getpid()}-") as tmp:
        path = Path(tmp, f"image.{fmt}")
        if fmt == "exr":
            from tessera_base.exr_header import noise_attributes

            s = spec.settings
            kind = farm_variance_kind(s, aovs)
            metadata = images.render_metadata(s.max_spp if s.adaptive else s.spp, s.sample_seed, spec.scene_name,
                                              s.integrator, kind)
            # The noise asked for and reached, as a local render writes them (the scene
            # file's own hash is local only: the farm holds the uploaded bundle).
            layers = aovs or {}
            metadata.update(noise_attributes(s.target_error, in_crop(s, rgba), in_crop(s, layers.get("variance")),
                                             in_crop(s, layers.get("spp")), kind))
            if s.auto_pilot:
                metadata["tessera:auto"] = s.auto_pilot
            images.write_exr(path, rgba, metadata, aovs=aovs, crop=s.crop)
        else:
            s = spec.settings  # a crop's PNG is the crop (a layer read from its EXR already is)
            full_frame = rgba.shape[:2] == (s.height, s.width)
            images.write_png_preview(path, in_crop(s, rgba) if full_frame else rgba)
        return path.read_bytes()
