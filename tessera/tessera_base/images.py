"""Image files: float RGBA EXR and tonemapped sRGB PNG previews, through OpenImageIO.

Used by the local render and by the service's merger, so both write identical files.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

# EXR channel names of each AOV (OpenEXR layer naming: "layer.channel"; docs/aovs.md).
# variance and spp are also the per-pixel noise estimate `tessera compare` reads:
# variance.R/G/B the unbiased sample variance of one sample of the pixel (divide by spp for
# the variance of the pixel's mean), spp the pixel's sample count.
AOV_EXR_CHANNELS = {
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "normal": ("N.X", "N.Y", "N.Z"),
    "depth": ("Z",),
    "spp": ("spp",),
    "variance": ("variance.R", "variance.G", "variance.B"),
    # Not rendered: Open Image Denoise's image from RGB, albedo and N (tessera_base.denoise,
    # docs/denoise.md). R, G, B stay the raw estimate.
    "denoised": ("denoised.R", "denoised.G", "denoised.B"),
}
VARIANCE_CHANNELS = AOV_EXR_CHANNELS["variance"]
SPP_CHANNEL = AOV_EXR_CHANNELS["spp"][0]

# What the variance channels mean, in the EXR header attribute VARIANCE_ATTRIBUTE:
#   "per-sample": the unbiased sample variance of one sample of the pixel (variance of the
#       mean = this / spp, spp - 1 degrees of freedom); the integrators without splats.
#   "batch-means:K": the estimated variance of the pixel's mean itself, from the spread of
#       K independent batch images (K - 1 degrees of freedom; convergence.VARIANCE_BATCHES);
#       light and bdpt, whose splats land on other pixels than their samples'.
# An EXR without the attribute (written before it existed) has no trustworthy variance:
# light and bdpt images then carried only the camera half of their estimate.
VARIANCE_ATTRIBUTE = "tessera:variance"
VARIANCE_PER_SAMPLE = "per-sample"
_BATCH_MEANS = "batch-means:"


def batch_means_kind(batches: int) -> str:
    return f"{_BATCH_MEANS}{int(batches)}"


def parse_variance_kind(kind: str | None) -> tuple[str, int | None]:
    """("per-sample", None) or ("batch-means", K); ValueError for anything else."""
    if kind == VARIANCE_PER_SAMPLE:
        return VARIANCE_PER_SAMPLE, None
    if kind and kind.startswith(_BATCH_MEANS):
        tail = kind[len(_BATCH_MEANS):]
        if tail.isdigit() and int(tail) >= 2:
            return "batch-means", int(tail)
    raise ValueError(f"unknown variance kind {kind!r} (known: {VARIANCE_PER_SAMPLE}, "
                     f"{_BATCH_MEANS}K with K >= 2)")


# Linear Rec.709 primaries and D65 white (x, y of R, G, B, white): the EXR
# `chromaticities` attribute, so compositing tools need not guess the colour space.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)


def write_exr(path: str | Path, rgba: np.ndarray, metadata: dict[str, str] | None = None,
              aovs: dict[str, np.ndarray] | None = None,
              crop: tuple[int, int, int, int] | None = None) -> None:
    """Writes float32 linear RGBA (h, w, 4) as a float EXR (zip compression, lossless),
    with each AOV (name -> (h, w[, c])) as extra channels named by AOV_EXR_CHANNELS.
    `crop` (x0, y0, x1, y1; x1, y1 exclusive): only that region of the full-frame arrays,
    as the data window, with the full frame as the display window (pbrt's --cropwindow)."""
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    h, w, c = rgba.shape
    names = list(("R", "G", "B", "A")[:c])
    layers = [rgba]
    for name, layer in (aovs or {}).items():
        if name not in AOV_EXR_CHANNELS:
            raise ValueError(f"unknown AOV {name!r} (known: {', '.join(AOV_EXR_CHANNELS)})")
        channels = AOV_EXR_CHANNELS[name]
        layer = np.asarray(layer, dtype=np.float32)
        if layer.size != h * w * len(channels) or layer.shape[:2] != (h, w):
            raise ValueError(f"AOV {name} has shape {layer.shape}, expected {(h, w, len(channels))}")
        names += channels
        layers.append(layer.reshape(h, w, len(channels)))
    pixels = np.ascontiguousarray(np.concatenate(layers, axis=2))
    full_w, full_h = w, h
    if crop is not None:
        x0, y0, x1, y1 = check_crop(crop, w, h)
        pixels, w, h = np.ascontiguousarray(pixels[y0:y1, x0:x1]), x1 - x0, y1 - y0
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
    if crop is not None:
        spec.x, spec.y = x0, y0
        spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, full_w, full_h
    spec.channelnames = tuple(names)
    if "Z" in names:
        spec.z_channel = names.index("Z")
    spec.attribute("compression", "zip")
    spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), REC709_CHROMATICITIES)
    for key, value in (metadata or {}).items():
        spec.attribute(key, str(value))
    _write(path, spec, pixels)


def check_crop(crop: tuple[int, int, int, int], width: int, height: int) -> tuple[int, int, int, int]:
    """The crop region (x0, y0, x1, y1), x1 and y1 exclusive; ValueError unless it is a
    non-empty region inside the width x height frame."""
    x0, y0, x1, y1 = (int(v) for v in crop)
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise ValueError(f"crop {x0},{y0},{x1},{y1} is not a non-empty region of the "
                         f"{width}x{height} frame (x0,y0,x1,y1 with x1, y1 exclusive)")
    return x0, y0, x1, y1


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """Every channel of an image by name: {name: float32 (h, w)}."""
    pixels, names = _read_all(path)
    return {name: pixels[:, :, i] for i, name in enumerate(names)}


def read_exr_aovs(path: str | Path) -> dict[str, np.ndarray]:
    """The AOVs present in an EXR written by write_exr: {name: float32 (h, w, c)}."""
    channels = read_exr_channels(path)
    return {name: np.stack([channels[c] for c in names], axis=2)
            for name, names in AOV_EXR_CHANNELS.items() if all(c in channels for c in names)}


def render_metadata(spp: int, seed: int, scene_name: str, integrator: str | None = None,
                    variance_kind: str | None = None) -> dict[str, str]:
    """EXR header attributes describing how an image was rendered (local and farm alike):
    spp, seed, scene, the Tessera version, the integrator as asked for (`auto` unresolved)
    and, when the image carries variance channels, what they mean (VARIANCE_ATTRIBUTE)."""
    from . import __version__

    meta = {"tessera:spp": str(spp), "tessera:seed": str(seed), "tessera:scene": scene_name,
            "tessera:version": __version__}
    if integrator:
        meta["tessera:integrator"] = integrator
    if variance_kind:
        meta[VARIANCE_ATTRIBUTE] = variance_kind
    return meta


def read_exr(path: str | Path) -> np.ndarray:
    """Reads an image as float32 (h, w, c), channels ordered R, G, B, A by name."""
    pixels, names = _read_all(path)
    order = [names.index(n) for n in ("R", "G", "B", "A") if n in names]
    return pixels[:, :, order]


def _read_all(path: str | Path) -> tuple[np.ndarray, list[str]]:
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
    return np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels), names


@dataclass
class RenderImage:
    """An EXR as Tessera writes it: RGBA, and the noise estimate when it carries one."""
    rgba: np.ndarray                     # float32 (h, w, 4); A is 1 when the file has none
    variance: np.ndarray | None          # float32 (h, w, 3): per-sample variance
    spp: np.ndarray | None               # float32 (h, w): samples per pixel
    metadata: dict[str, str] = field(default_factory=dict)
    # What `variance` means (VARIANCE_ATTRIBUTE); read_render takes it from the metadata.
    variance_kind: str | None = None


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
                       None if spp is None else np.ascontiguousarray(spp[:, :, 0]), metadata,
                       metadata.get(VARIANCE_ATTRIBUTE))


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
