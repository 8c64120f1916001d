"""The provenance attributes a local render adds to its EXR header beyond
images.render_metadata (all under the `tessera:` prefix, docs/aovs.md): the scene file's
SHA-256, the noise target asked for and the noise the image reached."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from . import images
from .convergence import _LUMINANCE


def scene_sha256(path: str | Path) -> str:
    """SHA-256 of the scene file's bytes (not of the layers or textures it references)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def reached_error(rgba: np.ndarray, variance: np.ndarray | None, spp: np.ndarray | None,
                  variance_kind: str | None) -> float | None:
    """The image's relative noise, measured as the noise target measures a tile
    (convergence.tile_error): the RMS over pixels of the luminance's standard error over the
    luminance, luminances floored at 1 % of the mean (and 1e-4). None without variance."""
    if variance is None or spp is None or variance_kind is None:
        return None
    kind = images.parse_variance_kind(variance_kind)[0]
    var = variance.astype(np.float64) @ (_LUMINANCE ** 2)
    if kind == images.VARIANCE_PER_SAMPLE:
        var = var / np.maximum(spp.astype(np.float64).reshape(var.shape), 1.0)
    lum = rgba[..., :3].astype(np.float64) @ _LUMINANCE
    floor = max(1e-4, 0.01 * float(np.mean(np.abs(lum))))
    return float(np.sqrt(np.mean(var / np.maximum(np.abs(lum), floor) ** 2)))


def provenance(scene: str | Path, target_error: float | None, rgba: np.ndarray,
               variance: np.ndarray | None, spp: np.ndarray | None,
               variance_kind: str | None) -> dict[str, str]:
    return {"tessera:scene_sha256": scene_sha256(scene),
            **noise_attributes(target_error, rgba, variance, spp, variance_kind)}


def noise_attributes(target_error: float | None, rgba: np.ndarray, variance: np.ndarray | None,
                     spp: np.ndarray | None, variance_kind: str | None) -> dict[str, str]:
    """The noise target asked for and the noise reached (reached_error), as header
    attributes; local renders and the farm's merge write them alike."""
    out = {}
    if target_error is not None:
        out["tessera:target_error"] = f"{target_error:g}"
    error = reached_error(rgba, variance, spp, variance_kind)
    if error is not None:
        out["tessera:reached_error"] = f"{error:.6g}"
    return out
