"""Whether a stage without UsdLux lights is lit by its own emission: the power its
materials emit (constant or textured), measured, against the power the default lighting
would deliver to the same scene (docs/scene-translation.md, "Light-less stages")."""
from __future__ import annotations

import glob
import math

import numpy as np

# Emission lights a light-less stage when it emits at least this fraction of the power the
# default lighting would deliver to the scene's bounding sphere. The bundled Cornell box
# (its light an emissive quad of radiance (17, 12, 4)) emits 8.4 % of it; an asset whose
# emission is only details (screens, LEDs, a helmet's glowing trims, an emissive map of mean
# 0.03 over a surface of 2.5 pi R^2) about 3 %.
EMISSION_LIGHTS_FRACTION = 0.05
REC709 = np.array([0.2126, 0.7152, 0.0722])
# The end of the line a weakly emitting stage gets, lit by default or (job setting) not.
EMISSION_DEFAULT_LIT = "the emission still shows, the default lighting lights the rest"
EMISSION_UNLIT = "with default lighting off, the emission alone lights it (dimly)"


def default_lighting_power(radius: float, dome_radiance: float, key_illuminance: float) -> float:
    """The power the default lighting delivers onto a sphere of `radius` (the scene's
    bounds): a uniform dome of radiance L gives every surface element pi L (4 pi R^2 of
    them); the distant key light gives E over the sphere's cross-section pi R^2."""
    return math.pi * dome_radiance * 4.0 * math.pi * radius * radius + key_illuminance * math.pi * radius * radius


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, None)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


_STATS: dict = {}


def texture_output_stats(tex: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """(mean, max) RGB over every texel of a texture's image(s) of what it emits: the
    output max(0, texel x scale + bias), as the core reads it (sRGB decoded, grey images
    replicated, a scalar output on all three channels). None when no image can be read
    (the core then uses the fallback)."""
    import OpenImageIO as oiio

    files = [tex["file"]]
    if tex.get("udim") or "<UDIM>" in str(tex["file"]):
        files = tex.get("udim_files") or sorted(glob.glob(str(tex["file"]).replace("<UDIM>", "1[0-9][0-9][0-9]")))
    key = (tuple(files), tex.get("color_space"), tex.get("channel"), tuple(tex["scale"]), tuple(tex["bias"]))
    if key in _STATS:
        return _STATS[key]
    scale, bias = np.asarray(tex["scale"], np.float64), np.asarray(tex["bias"], np.float64)
    total, peak, count = np.zeros(4), np.zeros(4), 0
    for f in files:
        buf = oiio.ImageBuf(str(f))
        px = None if buf.has_error else buf.get_pixels(oiio.FLOAT)
        if px is None:
            oiio.geterror()
            continue
        px = np.asarray(px, np.float32)
        px = px[:, :, None] if px.ndim == 2 else px[:, :, :4]
        c = px.shape[2]
        rgba = np.empty(px.shape[:2] + (4,), np.float32)
        rgba[..., :3] = px[..., :3] if c >= 3 else px[..., :1]
        rgba[..., 3] = px[..., 3] if c == 4 else (px[..., 1] if c == 2 else 1.0)
        if str(tex.get("color_space", "raw")).lower() == "srgb":
            rgba[..., :3] = _srgb_to_linear(rgba[..., :3])
        out = np.maximum(0.0, rgba.reshape(-1, 4) * scale + bias)
        total += out.sum(axis=0, dtype=np.float64)
        peak = np.maximum(peak, out.max(axis=0))
        count += len(out)
    if count == 0:
        _STATS[key] = None
        return None
    mean = total / count
    pick = {"r": 0, "g": 1, "b": 2, "a": 3}.get(tex.get("channel", "rgb"))
    result = (np.full(3, mean[pick]), np.full(3, peak[pick])) if pick is not None else (mean[:3], peak[:3])
    _STATS[key] = result
    return result


def material_emission(row: dict, textures: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(mean, max) emitted radiance of a material row over its surface: its constant, or
    its emissive texture's output (whose constant is only a fallback)."""
    t = row["textures"].get("emissiveColor")
    if t is not None:
        stats = texture_output_stats(textures[t])
        if stats is not None:
            return stats
        fb = np.maximum(0.0, np.asarray(textures[t]["fallback"][:3], np.float64))
        return fb, fb
    c = np.maximum(0.0, np.asarray(row["values"]["emissiveColor"], np.float64))
    return c, c


def _areas(positions: np.ndarray, indices: np.ndarray) -> np.ndarray:
    if len(indices) == 0:
        return np.zeros(0)
    p = np.asarray(positions, np.float64)[np.asarray(indices, np.int64)]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def emitted_power(rows, textures, meshes) -> tuple[float, int]:
    """(power, emitting triangle count) of material emission: the sum over triangles of
    pi x area x luminance of their material's mean radiance, x2 when two-sided. `meshes`:
    (positions, indices, triangle_material, area scales) with one area scale per copy
    (1 for the flat mesh, an instance's |det|^(2/3) per instance of a prototype)."""
    power_per_row, emits = np.zeros(max(len(rows), 1)), np.zeros(max(len(rows), 1), bool)
    for m, row in enumerate(rows):
        mean, peak = material_emission(row, textures)
        emits[m] = bool((peak > 0).any())  # provably zero when no texel emits
        power_per_row[m] = math.pi * float(REC709 @ mean) * (2.0 if row["two_sided"] else 1.0)
    power, count = 0.0, 0
    for positions, indices, tri_material, scales in meshes:
        tri_material = np.minimum(np.asarray(tri_material, np.int64), len(emits) - 1)
        hot = emits[tri_material]
        if not hot.any():
            continue
        areas = _areas(positions, np.asarray(indices)[hot])
        copies = float(np.sum(scales))
        power += float(areas @ power_per_row[tri_material[hot]]) * copies
        count += int(hot.sum()) * len(scales)
    return power, count
