"""Tessellation of UsdGeom implicit prims and of UsdLux area-light shapes, and the
blackbody colour of `colorTemperature`. Everything returns plain numpy arrays in the
prim's local space; the translator applies transforms and materials.

Shapes follow the UsdGeom schema: Sphere(radius), Cube(size, centred), Cylinder/Cone/
Capsule(radius, height along `axis`, centred; Cone apex at +height/2), Plane(width along
the first in-plane axis, length along the second, facing +axis).
"""
from __future__ import annotations

import math

import numpy as np

SEGMENTS = 48   # around an axis
RINGS = 24      # pole to pole

# Local frames: (u, v, w) where w is the schema `axis`.
_AXES = {"X": (1, 2, 0), "Y": (2, 0, 1), "Z": (0, 1, 2)}


def _to_axis(p: np.ndarray, axis: str) -> np.ndarray:
    """Maps points built around +Z to points built around `axis` (a cyclic permutation,
    so orientation is kept)."""
    u, v, w = _AXES.get(axis, _AXES["Z"])
    out = np.empty_like(p)
    out[..., u], out[..., v], out[..., w] = p[..., 0], p[..., 1], p[..., 2]
    return out


def _grid_quads(rows: int, cols: int, closed: bool) -> np.ndarray:
    """Quads (as two triangles) over a rows x cols vertex grid, wrapping columns if closed."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols if closed else cols - 1), indexing="ij")
    c1 = (c + 1) % cols
    a, b, d, e = r * cols + c, r * cols + c1, (r + 1) * cols + c, (r + 1) * cols + c1
    return np.concatenate([np.stack([a, b, e], -1).reshape(-1, 3), np.stack([a, e, d], -1).reshape(-1, 3)])


def _revolve(profile_r: np.ndarray, profile_z: np.ndarray, normals_rz: np.ndarray | None):
    """Surface of revolution about +Z from a profile running from bottom to top. Returns
    (points, triangles, per-vertex normals) wound counter-clockwise seen from outside."""
    phi = np.linspace(0.0, 2 * math.pi, SEGMENTS, endpoint=False)
    cos, sin = np.cos(phi), np.sin(phi)
    pts = np.stack([profile_r[:, None] * cos, profile_r[:, None] * sin,
                    np.broadcast_to(profile_z[:, None], (len(profile_r), SEGMENTS))], -1).reshape(-1, 3)
    tris = _grid_quads(len(profile_r), SEGMENTS, closed=True)
    # Rows of radius 0 (poles, apexes) collapse: drop their zero-area triangles.
    row = tris // SEGMENTS
    pole = profile_r[row] == 0.0
    tris = tris[~((pole[:, 0] & pole[:, 1]) | (pole[:, 1] & pole[:, 2]) | (pole[:, 0] & pole[:, 2]))]
    nrm = None
    if normals_rz is not None:
        nrm = np.stack([normals_rz[:, 0:1] * cos, normals_rz[:, 0:1] * sin,
                        np.broadcast_to(normals_rz[:, 1:2], (len(profile_r), SEGMENTS))], -1).reshape(-1, 3)
    return pts, tris, nrm


def _cap(z: float, radius: float, up: bool):
    """A disk at height z facing +Z (up) or -Z, as a triangle fan around its centre."""
    phi = np.linspace(0.0, 2 * math.pi, SEGMENTS, endpoint=False)
    ring = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full(SEGMENTS, z)], -1)
    pts = np.vstack([[0.0, 0.0, z], ring])
    k = np.arange(SEGMENTS)
    tris = np.stack([np.zeros(SEGMENTS, int), 1 + k, 1 + (k + 1) % SEGMENTS], -1)
    if not up:
        tris = tris[:, ::-1]
    nrm = np.tile([0.0, 0.0, 1.0 if up else -1.0], (SEGMENTS + 1, 1))
    return pts, tris, nrm


def _merge(parts):
    pts, tris, nrm, off = [], [], [], 0
    for p, t, n in parts:
        pts.append(p)
        tris.append(t + off)
        nrm.append(n)
        off += len(p)
    return np.vstack(pts), np.vstack(tris), np.vstack(nrm)


def sphere(radius: float):
    theta = np.linspace(math.pi, 0.0, RINGS + 1)  # bottom pole to top pole
    nrz = np.stack([np.sin(theta), np.cos(theta)], -1)
    return _revolve(radius * nrz[:, 0], radius * nrz[:, 1], nrz)


def capsule(radius: float, height: float, axis: str):
    """Cylinder of length `height` with hemispherical caps (total length height + 2r)."""
    half = RINGS // 2
    lower = np.linspace(math.pi, math.pi / 2, half + 1)
    upper = np.linspace(math.pi / 2, 0.0, half + 1)
    theta = np.concatenate([lower, upper])
    z = np.concatenate([np.cos(lower) * radius - height / 2, np.cos(upper) * radius + height / 2])
    nrz = np.stack([np.sin(theta), np.cos(theta)], -1)
    p, t, n = _revolve(radius * nrz[:, 0], z, nrz)
    return _to_axis(p, axis), t, _to_axis(n, axis)


def cylinder(radius: float, height: float, axis: str):
    side = _revolve(np.array([radius, radius]), np.array([-height / 2, height / 2]),
                    np.array([[1.0, 0.0], [1.0, 0.0]]))
    p, t, n = _merge([side, _cap(-height / 2, radius, False), _cap(height / 2, radius, True)])
    return _to_axis(p, axis), t, _to_axis(n, axis)


def cone(radius: float, height: float, axis: str):
    slope = math.hypot(radius, height)
    nr, nz = (height / slope, radius / slope) if slope > 0 else (1.0, 0.0)
    side = _revolve(np.array([radius, 0.0]), np.array([-height / 2, height / 2]), np.array([[nr, nz], [nr, nz]]))
    p, t, n = _merge([side, _cap(-height / 2, radius, False)])
    return _to_axis(p, axis), t, _to_axis(n, axis)


def cube(size: float):
    h = size / 2
    pts, tris, nrm = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            u, v = np.zeros(3), np.zeros(3)
            u[(axis + 1) % 3], v[(axis + 2) % 3] = 1.0, 1.0
            if sign < 0:
                u, v = v, u  # keep u x v along the outward normal
            corners = [normal * h + (su * u + sv * v) * h for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            base = len(pts) * 4
            pts.append(corners)
            tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            nrm.append([normal] * 4)
    return np.array(pts).reshape(-1, 3), np.array(tris), np.array(nrm).reshape(-1, 3)


def plane(width: float, length: float, axis: str):
    w, l_ = width / 2, length / 2
    p = np.array([[-w, -l_, 0.0], [w, -l_, 0.0], [w, l_, 0.0], [-w, l_, 0.0]])
    t = np.array([[0, 1, 2], [0, 2, 3]])
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    return _to_axis(p, axis), t, _to_axis(n, axis)


# -- light shapes -----------------------------------------------------------------------
def disk_light(radius: float):
    """A disk in local XY emitting along local -Z: wound so its geometric normal is -Z."""
    p, t, _ = _cap(0.0, radius, up=False)
    return p, t


def cylinder_light(radius: float, length: float):
    """The side of a cylinder along local X, wound so its normals face outward."""
    p, t, _ = _revolve(np.array([radius, radius]), np.array([-length / 2, length / 2]), None)
    return _to_axis(p, "X"), t


# -- colour temperature -----------------------------------------------------------------
_XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                           [-0.9692660, 1.8760108, 0.0415560],
                           [0.0556434, -0.2040259, 1.0572252]])


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Linear Rec.709 colour of a blackbody, normalised to luminance (CIE Y) 1.

    Chromaticity from the cubic-spline fit of the Planckian locus by Kim et al. (2002,
    US patent 7,024,034; accurate to ~1e-3 in xy over 1667-25000 K); clamped to that range.
    """
    t = min(max(float(kelvin), 1667.0), 25000.0)
    if t <= 4000:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    xyz = np.array([x / y, 1.0, (1.0 - x - y) / y])
    rgb = _XYZ_TO_REC709 @ xyz
    # Very warm temperatures fall outside Rec.709: clip, then restore luminance 1.
    rgb = np.maximum(rgb, 0.0)
    lum = float(np.dot([0.2126729, 0.7151522, 0.0721750], rgb))
    return rgb / lum
