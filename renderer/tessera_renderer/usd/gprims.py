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


# -- NurbsPatch ------------------------------------------------------------------------
NURBS_SEGMENTS = 8  # samples per knot span and direction (a span is one polynomial piece)


def bspline_basis(knots: np.ndarray, order: int, count: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The B-spline basis functions N_i (i < count) of `order` over `knots` at parameters t
    and their derivatives, each a (len(t), count) matrix: the Cox-de Boor recursion and
    dN_i,p = p N_i,p-1 / (k_i+p - k_i) - p N_i+1,p-1 / (k_i+p+1 - k_i+1) (The NURBS Book,
    eqs. 2.5 and 2.7; 0/0 = 0). The half-open spans put t at the range's end, knots[count],
    in the last non-empty span, so the closing row of a tessellation lands on the last
    control point of a clamped knot vector, with the span's own derivative."""
    k = np.asarray(knots, np.float64)
    t = np.asarray(t, np.float64)
    n = ((k[None, :-1] <= t[:, None]) & (t[:, None] < k[None, 1:])).astype(np.float64)
    end = t >= k[count]
    if end.any():
        last = max(i for i in range(count) if k[i] < k[i + 1] or i == 0)
        n[end] = 0.0
        n[end, last] = 1.0

    def ratio(num, den):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)

    lower = n
    for p in range(1, order):  # degree p from degree p - 1
        m = n.shape[1] - 1
        lower = n
        a = ratio(t[:, None] - k[None, :m], k[p:p + m] - k[:m])
        b = ratio(k[None, p + 1:p + 1 + m] - t[:, None], k[p + 1:p + 1 + m] - k[1:1 + m])
        n = a * n[:, :m] + b * n[:, 1:m + 1]
    p = order - 1
    dn = p * (ratio(lower[:, :count], k[p:p + count] - k[:count]) -
              ratio(lower[:, 1:count + 1], k[p + 1:p + 1 + count] - k[1:1 + count]))
    return n[:, :count], dn


def _nurbs_parameters(knots: np.ndarray, lo: float, hi: float, order: int, min_pieces: int = 0) -> np.ndarray:
    """NURBS_SEGMENTS samples on every non-empty knot span within [lo, hi] (one where the
    order is 2: a linear span is flat), ends included; at least `min_pieces` over the whole
    range (a trimmed patch: its trim cuts the grid's triangles)."""
    breaks = np.unique(np.clip(knots, lo, hi))
    spans = max(1, int(np.count_nonzero(np.diff(breaks) > 0)))
    pieces_per_span = max(1 if order == 2 else NURBS_SEGMENTS, -(-min_pieces // spans))
    pieces = [np.linspace(a, b, pieces_per_span, endpoint=False) for a, b in zip(breaks[:-1], breaks[1:]) if b > a]
    return np.concatenate(pieces + [[hi]]) if pieces else np.array([lo, hi])


def nurbs_patch(u_count: int, v_count: int, u_order: int, v_order: int, u_knots, v_knots, points,
                weights=None, u_range=None, v_range=None, min_pieces: int = 0):
    """A UsdGeomNurbsPatch (rational or polynomial, untrimmed) as triangles: (points,
    triangles, per-vertex normals, per-vertex (u, v)). Control points are laid out u
    fastest (points[v * u_count + u]), as RiNuPatch lays them out; the front face is the
    side dP/du x dP/dv points to. ValueError names what is inconsistent."""
    cps = np.asarray(points, np.float64).reshape(-1, 3)
    uk, vk = np.asarray(u_knots, np.float64), np.asarray(v_knots, np.float64)
    if u_order < 2 or v_order < 2 or u_count < u_order or v_count < v_order:
        raise ValueError(f"orders {u_order} x {v_order} need at least that many control points "
                         f"(has {u_count} x {v_count})")
    if len(cps) != u_count * v_count:
        raise ValueError(f"{len(cps)} points for {u_count} x {v_count} control vertices")
    if len(uk) != u_count + u_order or len(vk) != v_count + v_order:
        raise ValueError(f"knot counts {len(uk)} and {len(vk)}; the schema needs vertex count + order "
                         f"({u_count + u_order} and {v_count + v_order})")
    if np.any(np.diff(uk) < 0) or np.any(np.diff(vk) < 0) or not (np.isfinite(uk).all() and np.isfinite(vk).all()):
        raise ValueError("knots must be finite and non-decreasing")
    w = np.ones(len(cps)) if weights is None or len(weights) == 0 else np.asarray(weights, np.float64)
    if len(w) != len(cps) or not (w > 0).all():
        raise ValueError(f"pointWeights must be {len(cps)} positive values")
    u_lo, u_hi = (uk[u_order - 1], uk[u_count]) if u_range is None else u_range
    v_lo, v_hi = (vk[v_order - 1], vk[v_count]) if v_range is None else v_range
    u_lo, u_hi = max(u_lo, uk[u_order - 1]), min(u_hi, uk[u_count])
    v_lo, v_hi = max(v_lo, vk[v_order - 1]), min(v_hi, vk[v_count])
    if not (u_hi > u_lo and v_hi > v_lo):
        raise ValueError("the parameter range is empty")
    us = _nurbs_parameters(uk, u_lo, u_hi, u_order, min_pieces)
    vs = _nurbs_parameters(vk, v_lo, v_hi, v_order, min_pieces)
    bu, dbu = bspline_basis(uk, u_order, u_count, us)
    bv, dbv = bspline_basis(vk, v_order, v_count, vs)
    grid_w = w.reshape(v_count, u_count)
    homogeneous = cps.reshape(v_count, u_count, 3) * grid_w[..., None]

    def rational(basis_v, basis_u):
        return (np.einsum("ai,ijc,bj->abc", basis_v, homogeneous, basis_u),
                np.einsum("ai,ij,bj->ab", basis_v, grid_w, basis_u)[..., None])
    num, den = rational(bv, bu)
    surface = num / den  # (len(vs), len(us), 3): rows along v, u fastest
    # The quotient rule: S = A / w, dS = (dA - dw S) / w.
    num_u, den_u = rational(bv, dbu)
    num_v, den_v = rational(dbv, bu)
    du, dv = (num_u - den_u * surface) / den, (num_v - den_v * surface) / den
    nrm = np.cross(du, dv)
    length = np.linalg.norm(nrm, axis=-1, keepdims=True)
    # Where a derivative vanishes (a collapsed edge, a pole), the normal is left to the
    # triangles' geometry: None for the whole patch keeps the data plain.
    normals = (nrm / length).reshape(-1, 3) if (length > 0).all() else None
    tris = _grid_quads(len(vs), len(us), closed=False)
    uu, vv = np.meshgrid(us, vs)
    return surface.reshape(-1, 3), tris, normals, np.stack([uu.ravel(), vv.ravel()], -1)


# Trim curves: a trimmed patch's grid has at least this many pieces each way, each trim
# curve this many samples per knot span. A triangle is kept when its centroid is (the
# cut follows the grid: the kept area's error is a few cells' worth of area along the trim,
# about 0.2 % for a disc across half the patch).
TRIM_GRID_PIECES = 128
TRIM_CURVE_SAMPLES = 64


def trim_loops(counts, orders, vertex_counts, knots, ranges, points) -> list[np.ndarray]:
    """UsdGeomNurbsPatch trim curves as closed polylines in the patch's (u, v): one (N, 2)
    array per loop, its curves (rational B-splines over homogeneous (u, v, w) points, each
    over its `ranges` entry) joined in order. ValueError names what is inconsistent."""
    counts = np.asarray(counts, np.int64).reshape(-1)
    orders = np.asarray(orders, np.int64).reshape(-1)
    vertex_counts = np.asarray(vertex_counts, np.int64).reshape(-1)
    knots = np.asarray(knots, np.float64).reshape(-1)
    ranges = np.asarray(ranges, np.float64).reshape(-1, 2)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    n = int(counts.sum())
    if (counts < 1).any() or len(orders) != n or len(vertex_counts) != n or len(ranges) != n:
        raise ValueError(f"trim curves: counts sum to {n} curves, with {len(orders)} orders, "
                         f"{len(vertex_counts)} vertex counts and {len(ranges)} ranges")
    if (orders < 2).any() or (vertex_counts < orders).any():
        raise ValueError("trim curves: every curve needs an order >= 2 and at least that many points")
    if len(knots) != int((vertex_counts + orders).sum()) or len(pts) != int(vertex_counts.sum()):
        raise ValueError(f"trim curves: {len(knots)} knots and {len(pts)} points for vertex counts "
                         f"{vertex_counts.tolist()} and orders {orders.tolist()}")
    if not (np.isfinite(knots).all() and np.isfinite(pts).all() and (pts[:, 2] > 0).all()):
        raise ValueError("trim curves: points must be finite with positive w")
    loops, curve, k0, p0 = [], 0, 0, 0
    for count in counts:
        samples = []
        for _ in range(int(count)):
            order, nv = int(orders[curve]), int(vertex_counts[curve])
            k = knots[k0:k0 + nv + order]
            if np.any(np.diff(k) < 0):
                raise ValueError("trim curves: knots must be non-decreasing")
            lo, hi = max(ranges[curve, 0], k[order - 1]), min(ranges[curve, 1], k[nv])
            if not hi > lo:
                raise ValueError(f"trim curves: curve {curve} has an empty range")
            spans = max(1, int(np.count_nonzero(np.diff(np.unique(np.clip(k, lo, hi))) > 0)))
            t = np.linspace(lo, hi, spans * TRIM_CURVE_SAMPLES + 1)
            basis, _ = bspline_basis(k, order, nv, t)
            h = basis @ pts[p0:p0 + nv]
            samples.append(h[:, :2] / h[:, 2:3])
            curve, k0, p0 = curve + 1, k0 + nv + order, p0 + nv
        loops.append(np.concatenate(samples))
    return loops


def inside_trim(uv: np.ndarray, loops: list[np.ndarray]) -> np.ndarray:
    """Whether each (u, v) lies inside an odd number of the closed loops (even-odd: an
    outer loop keeps its inside, a loop within it cuts a hole), by ray crossing along +u."""
    u, v = uv[:, 0:1], uv[:, 1:2]
    inside = np.zeros(len(uv), bool)
    for loop in loops:
        a, b = loop, np.roll(loop, -1, axis=0)
        straddles = (a[None, :, 1] > v) != (b[None, :, 1] > v)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross_u = a[None, :, 0] + (v - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / \
                (b[None, :, 1] - a[None, :, 1])
        inside ^= (np.count_nonzero(straddles & (u < cross_u), axis=1) % 2).astype(bool)
    return inside


# -- Points ----------------------------------------------------------------------------
POINT_SEGMENTS, POINT_RINGS = 16, 8  # each point's sphere: 2 x 16 x 8 - 32 = 224 triangles


def _unit_point_sphere():
    theta = np.linspace(math.pi, 0.0, POINT_RINGS + 1)
    phi = np.linspace(0.0, 2 * math.pi, POINT_SEGMENTS, endpoint=False)
    nrm = np.stack([np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                    np.broadcast_to(np.cos(theta)[:, None], (len(theta), len(phi)))], -1).reshape(-1, 3)
    tris = _grid_quads(len(theta), len(phi), closed=True)
    row = tris // len(phi)
    pole = (row == 0) | (row == len(theta) - 1)
    tris = tris[~((pole[:, 0] & pole[:, 1]) | (pole[:, 1] & pole[:, 2]) | (pole[:, 0] & pole[:, 2]))]
    # The polyhedron is inscribed in the sphere: scaled so that its area is the sphere's
    # (4 pi), its silhouette covers what the sphere's does to about 1 %.
    e1, e2 = nrm[tris[:, 1]] - nrm[tris[:, 0]], nrm[tris[:, 2]] - nrm[tris[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=-1).sum()
    return nrm * math.sqrt(4 * math.pi / area), tris, nrm


POINT_SPHERE_TRIANGLES = len(_unit_point_sphere()[1])


def point_spheres(positions, widths):
    """UsdGeomPoints as spheres whose diameters are `widths` (one per point, or one for
    all): (points, triangles, per-vertex normals)."""
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    radius = np.broadcast_to(np.asarray(widths, np.float64).reshape(-1), (len(pos),)) * 0.5
    unit, tris, nrm = _unit_point_sphere()
    pts = (pos[:, None, :] + radius[:, None, None] * unit[None]).reshape(-1, 3)
    all_tris = (tris[None] + (np.arange(len(pos)) * len(unit))[:, None, None]).reshape(-1, 3)
    return pts, all_tris, np.tile(nrm, (len(pos), 1))
