"""Denoised previews: Intel Open Image Denoise (OIDN) over a finished image, guided by the
albedo and normal AOVs (docs/denoise.md).

An image operation of the foundation layer, run where images are finished: the local
render (tessera.local) and the service's merge. The renderer never sees it, and the
beauty is never replaced: the denoised image is one more layer (images.AOV_EXR_CHANNELS
"denoised"), since it is biased and `tessera compare`, the noise target and merging all
need the raw, unbiased estimate.

OIDN comes from PyPI's `pyoidn`, whose wheel ships the library (OIDN 2.5, CPU device);
the import is deferred so that everything else works without it.
"""
from __future__ import annotations

import numpy as np

# The AOVs the denoiser is fed; RenderSettings adds them when `denoise` is set.
DENOISE_AOVS = ("albedo", "normal")
# The EXR layer and the preview's file name suffix.
DENOISED_LAYER = "denoised"


class DenoiseError(Exception):
    """Denoising is impossible: the library is missing or the image lacks usable AOVs.
    The message is meant for the user as it is."""


def unavailable_reason() -> str | None:
    """None when OIDN can be loaded, else why not (in the user's terms)."""
    try:
        import pyoidn  # noqa: F401
    except Exception as exc:  # a missing package and a broken shared library alike
        return (f"denoising needs Intel Open Image Denoise, which cannot be loaded "
                f"({type(exc).__name__}: {exc}); install it with `pip install pyoidn`")
    return None


def denoise(rgba: np.ndarray, aovs: dict[str, np.ndarray]) -> np.ndarray:
    """The denoised RGB (float32 (h, w, 3)) of a linear HDR image `rgba` (h, w, >= 3),
    guided by aovs["albedo"] and aovs["normal"] (h, w, 3). Raises DenoiseError when OIDN
    cannot be loaded or the AOVs are missing or unusable; never changes its inputs."""
    color = np.asarray(rgba, dtype=np.float32)
    if color.ndim != 3 or color.shape[2] < 3 or min(color.shape[:2]) == 0:
        raise DenoiseError(f"cannot denoise an image of shape {color.shape}: expected (h, w, 3 or 4)")
    h, w = color.shape[:2]
    guides = {}
    for name in DENOISE_AOVS:
        layer = aovs.get(name)
        if layer is None:
            raise DenoiseError(f"cannot denoise: the image has no {name} AOV (the denoiser needs "
                               f"{' and '.join(DENOISE_AOVS)}; render with --denoise or --aovs "
                               f"{','.join(DENOISE_AOVS)})")
        layer = np.asarray(layer, dtype=np.float32)
        if layer.shape != (h, w, 3):
            raise DenoiseError(f"cannot denoise: the {name} AOV has shape {layer.shape}, "
                               f"expected {(h, w, 3)}")
        if not np.isfinite(layer).all():
            raise DenoiseError(f"cannot denoise: the {name} AOV has non-finite values")
        guides[name] = layer
    rgb = np.ascontiguousarray(color[..., :3])
    if not np.isfinite(rgb).all():
        raise DenoiseError("cannot denoise: the image has non-finite pixels")
    reason = unavailable_reason()
    if reason:
        raise DenoiseError(reason)
    import pyoidn

    # OIDN's ranges: albedo in [0, 1], normals in [-1, 1] (Tessera's are within them up to
    # rounding), colour non-negative. The clamps only guard against rounding.
    albedo = np.ascontiguousarray(np.clip(guides["albedo"], 0.0, 1.0))
    normal = np.ascontiguousarray(np.clip(guides["normal"], -1.0, 1.0))
    try:
        out = pyoidn.denoise(np.maximum(rgb, 0.0), albedo, normal, hdr=True, quality="high")
    except (RuntimeError, ValueError, TypeError) as exc:
        raise DenoiseError(f"Open Image Denoise failed: {exc}") from exc
    return np.ascontiguousarray(out, dtype=np.float32)
