"""UsdLux ShapingAPI as the core's shaped point lights (lights/light_shaping.h): the cone
(angle, softness), focus and focus tint, and IES profiles (`shaping:ies:file`, LM-63 read
here). The columns follow a point light's six in SceneData.point_lights; IES profiles go
to SceneData.ies_tables, which the columns name.

Conventions: the shaping axis is the light's -Z (its emission direction); an IES profile's
vertical angle 0 points along it and its horizontal angle 0 along the light's +X, 90 along
+Y (type C photometry). The files' horizontal symmetries are expanded: one angle (round),
0..90 (mirrored into each quadrant), 0..180 (mirrored about the 0-180 plane), 0..360. The
table is scaled to a peak of 1, so the light's intensity is its peak;
`shaping:ies:normalize` instead scales it to a mean of 1 over the sphere (the light's total
power unchanged).
"""
from __future__ import annotations

import math
import os

import numpy as np

from .authoring import authoring_layer
from .errors import read_float

IES_SAMPLES = 181  # lights/light_shaping.h kIesSamples: 0..180 degrees, 1 degree apart
IES_AZIMUTHS = 73  # kIesAzimuths: 0..360 degrees, 5 degrees apart
COLUMNS = 14  # after the six of a point light (renderer/python/module.cpp kShapingColumns)
IES_COLUMN = 10  # IES table index + 1 (0: none)
ABOUT_AXIS = 2.0  # column 0 of an area light shaped about the light's -Z, not its normal (1)


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


def _full_circle(h: np.ndarray, cd: np.ndarray, note) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal angles and candela[h, v] over 0..360 degrees, from the symmetries
    LM-63 allows: one angle (round), 0..90 (the quadrant mirrored about 90, 180 and 270),
    0..180 (mirrored about the 0-180 plane), or a full circle from 0."""
    if len(h) == 1:
        return np.array([0.0, 360.0]), np.vstack([cd, cd])
    if np.any(np.diff(h) <= 0) or h[0] != 0.0:
        raise IesError("horizontal angles must rise from 0")
    if h[-1] == 90.0:  # the four quadrants mirror the first
        h, cd = np.concatenate([h, 180.0 - h[-2::-1]]), np.vstack([cd, cd[-2::-1]])
    if h[-1] == 180.0:  # the other half mirrors this one
        h, cd = np.concatenate([h, 360.0 - h[-2::-1]]), np.vstack([cd, cd[-2::-1]])
    elif h[-1] < 360.0:
        if h[-1] > 180.0:
            note("IES horizontal angles end before 360 degrees; the rest of the circle is closed by interpolation")
            h, cd = np.concatenate([h, [360.0]]), np.vstack([cd, cd[:1]])
        else:
            raise IesError(f"horizontal angles end at {h[-1]:g} degrees (LM-63 allows 0, 90, 180 or 360)")
    if h[-1] > 360.0:
        raise IesError("horizontal angles beyond 360 degrees")
    return h, cd


def ies_profile(text: str, normalize: bool, note, angle_scale: float = 0.0) -> np.ndarray:
    """(IES_SAMPLES, IES_AZIMUTHS) factors over the angle off the axis and the horizontal
    angle about it (0 outside the file's vertical angles).
    `angle_scale` (shaping:ies:angleScale) rescales the profile's vertical angles about
    180 degrees, as UsdLux specifies it (RenderMan's profile scale): the light's angle
    theta reads the profile at (theta - 180) / (1 + angleScale) + 180 degrees; above 0 the
    profile widens, below it narrows. Without normalizing the factors are the candela over
    the file's peak; normalizing divides the rescaled table by its mean over the sphere."""
    v, h, cd = parse_ies(text)
    h, cd = _full_circle(h, cd, note)
    theta = np.arange(IES_SAMPLES, dtype=np.float64)
    if not (math.isfinite(angle_scale) and angle_scale > -1.0):
        note("shaping:ies:angleScale at or below -1 (or not finite) is ignored")
        angle_scale = 0.0
    read_at = (theta - 180.0) / (1.0 + angle_scale) + 180.0
    outside = (read_at < v[0]) | (read_at > v[-1])
    # Vertical first (each file column), then horizontal at the table's azimuths.
    by_v = np.array([np.interp(read_at, v, row) if len(v) > 1 else np.full(IES_SAMPLES, row[0]) for row in cd])
    by_v[:, outside] = 0.0
    phi = np.linspace(0.0, 360.0, IES_AZIMUTHS)
    table = np.array([np.interp(phi, h, by_v[:, i]) for i in range(IES_SAMPLES)])
    if not table.max() > 0:
        raise IesError("the profile emits nothing")
    if normalize:
        # Mean over the sphere: (1/4 pi) of the integral of f sin(theta) dtheta dphi.
        rad = np.radians(theta)
        around = np.trapezoid(table, np.radians(phi), axis=1)
        return table / (np.trapezoid(around * np.sin(rad), rad) / (4.0 * math.pi))
    # Over the file's own peak: rescaling the angles moves the peak, it does not raise it.
    return table / max(float(cd.max()), float(table.max()))


def _ies_table(translator, api, where: str) -> np.ndarray | None:
    """The light's IES table (shaping:ies:file read through the bundle sandbox), or None
    without one; a missing or unreadable file is a warning naming it."""
    t = translator.time
    asset = api.GetShapingIesFileAttr().Get(t)
    if asset is None or not asset.path:
        return None
    layer = authoring_layer(api.GetShapingIesFileAttr())
    path = translator.bundle.resolve_texture(asset, os.path.dirname(layer.realPath) if layer else None,
                                             where) if translator.bundle else None
    if path is None:
        translator.warn(f"{where}: IES profile {asset.path!r} is missing; the light is not shaped by it")
        return None
    try:
        return ies_profile(path.read_text(errors="replace"), bool(api.GetShapingIesNormalizeAttr().Get(t)),
                           translator._count_note, read_float(api.GetShapingIesAngleScaleAttr(), t))
    except (IesError, OSError) as err:
        translator.warn(f"{where}: IES profile {asset.path!r} cannot be read ({err}); "
                        f"the light is not shaped by it")
        return None


def shaping_columns(translator, prim) -> list[float] | None:
    """The shaping columns of a light prim with ShapingAPI, or None without it (or when
    every authored value leaves the light unshaped). An IES table is appended to
    translator.ies_tables and named by index."""
    from pxr import UsdLux

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
    ies = _ies_table(translator, api, where)
    if cutoff >= math.pi and focus == 0.0 and ies is None:
        return None
    m = translator.world_matrix(prim)
    axis = -np.asarray(m[2, :3], np.float64)  # the light's -Z in world space (row vectors)
    zero = np.asarray(m[0, :3], np.float64)  # its +X: the IES horizontal angle 0
    n, nz = float(np.linalg.norm(axis)), float(np.linalg.norm(zero))
    if not (n > 0 and nz > 0):
        translator.warn(f"{where}: the light's transform is degenerate; not shaped")
        return None
    table = 0.0
    if ies is not None:
        translator.ies_tables.append(ies.astype(np.float32))
        table = float(len(translator.ies_tables))
    return [1.0, *(axis / n), cutoff, smooth_start, focus, *tint, table, *(zero / nz)]


def unshaped_columns() -> list[float]:
    return [0.0] * COLUMNS


def along_axis_factor(translator, prim) -> float:
    """The shaping factor along the light's own -Z: all a DistantLight emits toward (its
    angular disk is taken as that one direction). A cone of any angle and focus leave it
    1; an IES profile scales it by its vertical-0 value (the same at every horizontal
    angle)."""
    from pxr import UsdLux

    if not prim.HasAPI(UsdLux.ShapingAPI):
        return 1.0
    table = _ies_table(translator, UsdLux.ShapingAPI(prim), str(prim.GetPath()))
    return 1.0 if table is None else float(table[0, 0])
