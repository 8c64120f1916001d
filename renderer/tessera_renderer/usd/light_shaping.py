"""UsdLux ShapingAPI as the core's shaped point lights (lights/light_shaping.h): the cone
(angle, softness), focus and focus tint, and IES profiles (`shaping:ies:file`, LM-63 read
here). The columns follow a point light's six in SceneData.point_lights.

Conventions: the shaping axis is the light's -Z (its emission direction); an IES profile's
vertical angle 0 points along it; the profile is averaged over its horizontal angles (a
note says so when they differ) and scaled to a peak of 1, so the light's intensity is its
peak; `shaping:ies:normalize` instead scales it to a mean of 1 over the sphere (the light's
total power unchanged).
"""
from __future__ import annotations

import math
import os

import numpy as np

from .errors import read_float

IES_SAMPLES = 181  # lights/light_shaping.h kIesSamples: 0..180 degrees, 1 degree apart
COLUMNS = 11 + IES_SAMPLES  # after the six of a point light


class IesError(ValueError):
    pass


def parse_ies(text: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertical angles, horizontal angles, candela[h, v]) of an LM-63 photometric file."""
    lines = text.splitlines()
    tilt = next((i for i, ln in enumerate(lines) if ln.strip().upper().startswith("TILT=")), None)
    if tilt is None:
        raise IesError("no TILT= line (not an LM-63 file)")
    tokens = " ".join(lines[tilt + 1:]).replace(",", " ").split()
    try:
        values = [float(t) for t in tokens]
    except ValueError as err:
        raise IesError(f"non-numeric photometric data ({err})") from None
    if lines[tilt].strip().upper() == "TILT=INCLUDE":
        if len(values) < 2:
            raise IesError("truncated TILT data")
        n_tilt = int(values[1])
        values = values[2 + 2 * n_tilt:]
    if len(values) < 13:
        raise IesError("truncated header")
    multiplier, n_v, n_h = values[2], int(values[3]), int(values[4])
    body = values[13:]
    if n_v < 1 or n_h < 1 or len(body) < n_v + n_h + n_v * n_h:
        raise IesError(f"{n_v} vertical x {n_h} horizontal angles but {len(body)} values")
    v = np.array(body[:n_v])
    h = np.array(body[n_v:n_v + n_h])
    cd = np.array(body[n_v + n_h:n_v + n_h + n_v * n_h]).reshape(n_h, n_v) * multiplier
    if np.any(np.diff(v) <= 0) or v[0] < 0 or v[-1] > 180 or not np.isfinite(cd).all() or (cd < 0).any():
        raise IesError("vertical angles must rise within 0..180 and candela be finite and >= 0")
    return v, h, cd


def ies_profile(text: str, normalize: bool, note, angle_scale: float = 0.0) -> np.ndarray:
    """IES_SAMPLES factors over the angle off the axis (0 outside the file's angles).
    `angle_scale` (shaping:ies:angleScale) rescales the profile's vertical angles about
    180 degrees, as UsdLux specifies it (RenderMan's profile scale): the light's angle
    theta reads the profile at (theta - 180) / (1 + angleScale) + 180 degrees; above 0 the
    profile widens, below it narrows. Without normalizing the factors are the candela over
    the file's peak; normalizing divides the rescaled profile by its mean over the sphere."""
    v, _, cd = parse_ies(text)
    mean = cd.mean(axis=0)
    if cd.shape[0] > 1 and np.abs(cd - mean).max() > 0.01 * max(mean.max(), 1e-30):
        note("IES profiles that vary with the horizontal angle are averaged over it (rotationally symmetric)")
    theta = np.arange(IES_SAMPLES, dtype=np.float64)
    if not (math.isfinite(angle_scale) and angle_scale > -1.0):
        note("shaping:ies:angleScale at or below -1 (or not finite) is ignored")
        angle_scale = 0.0
    read_at = (theta - 180.0) / (1.0 + angle_scale) + 180.0
    prof = np.interp(read_at, v, mean, left=0.0, right=0.0) if len(v) > 1 else np.full(IES_SAMPLES, mean[0])
    prof[(read_at < v[0]) | (read_at > v[-1])] = 0.0
    if not prof.max() > 0:
        raise IesError("the profile emits nothing")
    if normalize:
        # Mean over the sphere: integral of f(theta) sin(theta) dtheta / 2.
        rad = np.radians(theta)
        return prof / (0.5 * np.trapz(prof * np.sin(rad), rad))
    # Over the file's own peak: rescaling the angles moves the peak, it does not raise it.
    return prof / max(float(mean.max()), float(prof.max()))


def shaping_columns(translator, prim) -> list[float] | None:
    """The shaping columns of a light prim with ShapingAPI, or None without it (or when
    every authored value leaves the light unshaped)."""
    from pxr import UsdLux

    from .materials import _authoring_layer

    if not prim.HasAPI(UsdLux.ShapingAPI):
        return None
    t = translator.time
    api = UsdLux.ShapingAPI(prim)
    where = str(prim.GetPath())
    def value(attr, fallback):  # an authored 0 is a value (a closed cone), not the fallback
        v = attr.Get(t)
        return float(fallback if v is None else v)

    # The schema's fallback cone is 90 degrees: a shaped light emits into its -Z hemisphere.
    angle = value(api.GetShapingConeAngleAttr(), 90.0)
    softness = float(np.clip(value(api.GetShapingConeSoftnessAttr(), 0.0), 0.0, 1.0))
    focus = max(value(api.GetShapingFocusAttr(), 0.0), 0.0)
    if not all(math.isfinite(x) for x in (angle, softness, focus)):
        translator.warn(f"{where}: non-finite shaping values; the light is not shaped")
        return None
    tint = api.GetShapingFocusTintAttr().Get(t)
    tint = [float(x) for x in tint] if tint is not None else [0.0, 0.0, 0.0]
    cutoff = math.radians(min(max(angle, 0.0), 180.0))
    smooth_start = cutoff * (1.0 - softness)
    ies = None
    asset = api.GetShapingIesFileAttr().Get(t)
    if asset is not None and asset.path:
        layer = _authoring_layer(api.GetShapingIesFileAttr())
        path = translator.bundle.resolve_texture(asset, os.path.dirname(layer.realPath) if layer else None,
                                                 where) if translator.bundle else None
        if path is None:
            translator.warn(f"{where}: IES profile {asset.path!r} is missing; the light is not shaped by it")
        else:
            try:
                ies = ies_profile(path.read_text(errors="replace"),
                                  bool(api.GetShapingIesNormalizeAttr().Get(t)), translator._count_note,
                                  read_float(api.GetShapingIesAngleScaleAttr(), t))
            except (IesError, OSError) as err:
                translator.warn(f"{where}: IES profile {asset.path!r} cannot be read ({err}); "
                                f"the light is not shaped by it")
    if cutoff >= math.pi and focus == 0.0 and ies is None:
        return None
    m = translator.world_matrix(prim)
    axis = -np.asarray(m[2, :3], np.float64)  # the light's -Z in world space (row vectors)
    n = float(np.linalg.norm(axis))
    if not n > 0:
        translator.warn(f"{where}: the light's transform is degenerate; not shaped")
        return None
    return [1.0, *(axis / n), cutoff, smooth_start, focus, *tint,
            1.0 if ies is not None else 0.0, *(ies if ies is not None else np.zeros(IES_SAMPLES))]


def unshaped_columns() -> list[float]:
    return [0.0] * COLUMNS

