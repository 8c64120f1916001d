"""Image files: float RGBA EXR and tonemapped sRGB PNG previews, through OpenImageIO.

Used by the local render and by the service's merger, so both write identical files.
"""
from __future__ import annotations

from pathlib import Path

from dataclasses import dataclass, field

import numpy as np
import OpenImageIO as oiio

# The per-pixel noise estimate in Tessera's EXRs, named here and nowhere else (other layers,
# such as AOVs, bring their own names). variance.R/G/B: the unbiased sample variance of one
# sample of the pixel (divide by spp for the variance of the pixel's mean); spp: the
# pixel's sample count. `tessera compare` needs both.
VARIANCE_CHANNELS = ("variance.R", "variance.G", "variance.B")
SPP_CHANNEL = "spp"


def write_exr(path: str | Path, rgba: np.ndarray, metadata: dict[str, str] | None = None, *,
              variance: np.ndarray | None = None, spp: np.ndarray | None = None) -> None:
    """Writes float32 linear RGBA (h, w, 4) as a float EXR (zip compression, lossless);
    with `variance` (h, w, 3) and `spp` (h, w) also the VARIANCE_CHANNELS and SPP_CHANNEL."""
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    h, w, c = rgba.shape
    names = ["R", "G", "B", "A"][:c]
    layers = [rgba]
    if (variance is None) != (spp is None):
        raise ValueError("variance and spp are written together")
    if variance is not None:
        variance = np.asarray(variance, dtype=np.float32)
        spp = np.broadcast_to(np.asarray(spp, dtype=np.float32), (h, w))
        if variance.shape != (h, w, 3):
            raise ValueError(f"variance has shape {variance.shape}, expected {(h, w, 3)}")
        names += [*VARIANCE_CHANNELS, SPP_CHANNEL]
        layers += [variance, spp[:, :, None]]
    pixels = np.ascontiguousarray(np.concatenate(layers, axis=2)) if len(layers) > 1 else rgba
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    for key, value in (metadata or {}).items():
        spec.attribute(key, str(value))
    _write(path, spec, pixels)


def render_metadata(spp: int, seed: int, scene_name: str) -> dict[str, str]:
    """EXR header attributes describing how an image was rendered (local and farm alike)."""
    return {"tessera:spp": str(spp), "tessera:seed": str(seed), "tessera:scene": scene_name}


def read_exr(path: str | Path) -> np.ndarray:
    """Reads an image as float32 (h, w, c), channels ordered R, G, B, A by name."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"cannot open {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise OSError(f"cannot read {path}: {inp.geterror()}")
        names = list(spec.channelnames)
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    order = [names.index(n) for n in ("R", "G", "B", "A") if n in names]
    return pixels[:, :, order]


@dataclass
class RenderImage:
    """An EXR as Tessera writes it: RGBA, and the noise estimate when it carries one."""
    rgba: np.ndarray                     # float32 (h, w, 4); A is 1 when the file has none
    variance: np.ndarray | None          # float32 (h, w, 3): per-sample variance
    spp: np.ndarray | None               # float32 (h, w): samples per pixel
    metadata: dict[str, str] = field(default_factory=dict)


def read_render(path: str | Path, max_pixels: int | None = None) -> RenderImage:
    """Reads an EXR with its VARIANCE_CHANNELS and SPP_CHANNEL (None when absent). Raises
    OSError when the file cannot be read and ValueError when it has no R, G, B or more than
    `max_pixels` pixels (checked from the header, before any pixel is decoded)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"cannot open {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        if max_pixels is not None and spec.width * spec.height > max_pixels:
            raise ValueError(f"{path} is {spec.width}x{spec.height}, more than {max_pixels} pixels")
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise OSError(f"cannot read {path}: {inp.geterror()}")
        names = list(spec.channelnames)
        metadata = {a.name: str(a.value) for a in spec.extra_attribs}
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)

    def channels(wanted):
        return None if not all(n in names for n in wanted) else \
            pixels[:, :, [names.index(n) for n in wanted]]

    rgb = channels(("R", "G", "B"))
    if rgb is None:
        raise ValueError(f"{path} has no R, G, B channels (it has {', '.join(names)})")
    alpha = channels(("A",))
    rgba = np.concatenate([rgb, alpha if alpha is not None else np.ones_like(rgb[:, :, :1])], axis=2)
    variance, spp = channels(VARIANCE_CHANNELS), channels((SPP_CHANNEL,))
    return RenderImage(np.ascontiguousarray(rgba), None if variance is None else np.ascontiguousarray(variance),
                       None if spp is None else np.ascontiguousarray(spp[:, :, 0]), metadata)


def tonemap_srgb8(rgba: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (clamped, exposure in stops). Non-finite pixels show magenta
    so that they are noticed, not hidden."""
    rgb = np.asarray(rgba, dtype=np.float32)[:, :, :3] * np.float32(2.0 ** exposure)
    bad = ~np.isfinite(rgb).all(axis=2)
    rgb = np.clip(np.nan_to_num(rgb, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    out = np.round(srgb * 255.0).astype(np.uint8)
    out[bad] = (255, 0, 255)
    return out


def write_png_preview(path: str | Path, rgba: np.ndarray, exposure: float = 0.0) -> None:
    write_png(path, tonemap_srgb8(rgba, exposure))


def write_png(path: str | Path, rgb8: np.ndarray) -> None:
    """Writes uint8 (h, w, 3) as it is."""
    rgb8 = np.ascontiguousarray(rgb8, dtype=np.uint8)
    h, w, _ = rgb8.shape
    _write(path, oiio.ImageSpec(w, h, 3, oiio.UINT8), rgb8)


def _write(path: str | Path, spec: oiio.ImageSpec, pixels: np.ndarray) -> None:
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OSError(f"cannot create {path}: {oiio.geterror()}")
    try:
        if not out.open(str(path), spec):
            raise OSError(f"cannot open {path} for writing: {out.geterror()}")
        if not out.write_image(pixels):
            raise OSError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()
