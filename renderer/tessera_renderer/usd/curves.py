"""UsdGeom BasisCurves (Blender hair, Houdini curves): still curves of the world as
Embree round linear curves (a cone between spheres per segment of the evaluated polyline,
radius half the authored width: seen across, exactly the authored width), and moving,
instanced or emissive ones as closed tubes of triangles (the paths that only meshes take).

A tube of TUBE_SIDES sides whose circumradius makes its projected width, averaged over
view directions, equal the authored width (Cauchy: the mean width of a convex polygon is
its perimeter over pi); seen from any direction across the curve the projected width is
within [cos(pi / N), 1] of that, i.e. within 1.3 % of the authored width for N = 16.
Cubic curves (bezier, bspline, catmullRom; nonperiodic or periodic) are evaluated at
SAMPLES_PER_SEGMENT points per segment; `pinned` wrap is treated as nonperiodic (warning).
Widths: constant, uniform, varying and vertex interpolation; the schema's fallback width
is 1 when none is authored.
"""
from __future__ import annotations

import math

import numpy as np

TUBE_SIDES = 16
SAMPLES_PER_SEGMENT = 8
_RADIUS_SCALE = (math.pi / TUBE_SIDES) / math.sin(math.pi / TUBE_SIDES)

# Cubic basis matrices (rows: weights of the four control points for t^3, t^2, t, 1).
_BASES = {
    "bezier": (np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]], float), 3),
    "bspline": (np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]], float) / 6.0, 1),
    "catmullRom": (np.array([[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]], float) / 2.0, 1),
}


def _cubic(points: np.ndarray, basis: str, periodic: bool) -> np.ndarray | None:
    """Points along one cubic curve from its control points; None if too few."""
    m, step = _BASES[basis]
    pts = np.vstack([points, points[:3]]) if periodic else points
    n = len(pts)
    if n < 4:
        return None
    starts = np.arange(0, n - 3, step)
    if periodic:
        starts = starts[starts < len(points)]
    t = np.linspace(0.0, 1.0, SAMPLES_PER_SEGMENT + 1)[:-1]
    powers = np.stack([t ** 3, t ** 2, t, np.ones_like(t)], -1)   # (S, 4)
    weights = powers @ m                                          # (S, 4)
    segs = np.stack([pts[s:s + 4] for s in starts])               # (G, 4, 3)
    out = np.einsum("sk,gkd->gsd", weights, segs).reshape(-1, 3)
    if periodic:
        return out
    end = (np.ones((1, 4)) @ m) @ segs[-1]  # the last segment at t = 1
    return np.vstack([out, end])


def tube(path: np.ndarray, widths: np.ndarray, closed: bool):
    """(points, triangles, per-vertex normals) of a tube along a polyline."""
    k = len(path)
    if k < 2:
        return None
    if closed:
        tangents = np.roll(path, -1, 0) - np.roll(path, 1, 0)
    else:
        tangents = np.gradient(path, axis=0)
    tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-30)
    # A frame carried along the curve by projection (parallel transport, no twist flips).
    ref = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.empty_like(path)
    prev = ref - tangents[0] * (ref @ tangents[0])
    for i in range(k):
        cand = prev - tangents[i] * (prev @ tangents[i])
        norm = np.linalg.norm(cand)
        if norm < 1e-12:
            cand = np.cross(tangents[i], [1.0, 0, 0]) if abs(tangents[i, 0]) < 0.9 else np.cross(tangents[i], [0, 1.0, 0])
            norm = np.linalg.norm(cand)
        u[i] = prev = cand / norm
    v = np.cross(tangents, u)
    phi = np.linspace(0.0, 2 * math.pi, TUBE_SIDES, endpoint=False)
    radial = np.cos(phi)[None, :, None] * u[:, None, :] + np.sin(phi)[None, :, None] * v[:, None, :]
    r = 0.5 * widths[:, None, None] * _RADIUS_SCALE
    pts = (path[:, None, :] + r * radial).reshape(-1, 3)
    rows = k if closed else k - 1
    i, j = np.meshgrid(np.arange(rows), np.arange(TUBE_SIDES), indexing="ij")
    i1, j1 = (i + 1) % k, (j + 1) % TUBE_SIDES
    a, b, c, d = i * TUBE_SIDES + j, i * TUBE_SIDES + j1, i1 * TUBE_SIDES + j, i1 * TUBE_SIDES + j1
    tris = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return pts, tris, radial.reshape(-1, 3)


def curve_paths(prim, time, note):
    """The polylines of a BasisCurves prim in its local space: (points (k, 3), widths (k,),
    periodic) per drawable curve, or None (with a note, or nothing to draw)."""
    from pxr import UsdGeom

    curves = UsdGeom.BasisCurves(prim)
    points = curves.GetPointsAttr().Get(time)
    counts = curves.GetCurveVertexCountsAttr().Get(time)
    if points is None or counts is None or len(points) == 0 or len(counts) == 0:
        return None
    points = np.asarray(points, np.float64).reshape(-1, 3)
    counts = np.asarray(counts, np.int64)
    if counts.min() < 1 or counts.sum() != len(points):
        note("BasisCurves whose curveVertexCounts do not sum to their points are skipped")
        return None
    kind = str(curves.GetTypeAttr().Get(time) or "cubic")
    basis = str(curves.GetBasisAttr().Get(time) or "bezier")
    wrap = str(curves.GetWrapAttr().Get(time) or "nonperiodic")
    if wrap == "pinned":
        note("BasisCurves with wrap 'pinned' are drawn as nonperiodic")
    periodic = wrap == "periodic"
    if curves.GetNormalsAttr().HasAuthoredValue():
        note("BasisCurves with normals (oriented ribbons) are drawn as round tubes")
    if kind == "cubic" and basis not in _BASES:
        note(f"BasisCurves with basis {basis!r} are drawn through their control points (linear)")
        kind = "linear"
    widths = curves.GetWidthsAttr().Get(time)
    widths = np.asarray(widths, np.float64).reshape(-1) if widths is not None and len(widths) else np.ones(1)
    interp = curves.GetWidthsInterpolation()
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    paths = []
    for c, (s, n) in enumerate(zip(starts, counts)):
        ctrl = points[s:s + n]
        if interp == "constant" or len(widths) == 1:
            wc = np.full(n, widths[0])
        elif interp == "uniform" and len(widths) == len(counts):
            wc = np.full(n, widths[c])
        elif len(widths) == len(points):
            wc = widths[s:s + n]
        else:  # varying (one per segment end) or a count that fits nothing: along the curve
            note("BasisCurves widths other than constant, uniform or vertex are spread along each curve")
            wc = np.interp(np.linspace(0, 1, n), np.linspace(0, 1, len(widths)), widths)
        path = _cubic(ctrl, basis, periodic) if kind == "cubic" else ctrl
        if path is None:
            path = ctrl
        # Widths follow the curve's parameter (per control point, spread evenly).
        w = np.interp(np.linspace(0, 1, len(path)), np.linspace(0, 1, n), wc)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(path, axis=0), axis=1) > 0])
        if keep.sum() >= 2:
            paths.append((path[keep], w[keep], periodic))
    return paths or None


def curves_geometry(paths):
    """(points, triangles, per-corner normals, curve index per triangle) of the tubes
    along `paths` (curve_paths), in their space."""
    out_pts, out_tris, out_nrm, out_curve, offset = [], [], [], [], 0
    for c, (path, w, periodic) in enumerate(paths):
        p, t, nrm = tube(path, w, periodic)
        out_pts.append(p)
        out_tris.append(t + offset)
        out_nrm.append(nrm)
        out_curve.append(np.full(len(t), c))
        offset += len(p)
    tris = np.vstack(out_tris)
    nrm = np.vstack(out_nrm)
    return np.vstack(out_pts), tris, nrm[tris].astype(np.float32), np.concatenate(out_curve)


def native_curves(paths, m: np.ndarray, note):
    """World-space Embree round linear curves of `paths` under the row-vector transform m:
    (points float64 (P, 4) x y z radius, segments (S,) first point, flags (S,) neighbours). A
    non-uniform scale keeps round sections (radius by the mean scale, one note); a periodic
    curve is closed by repeating its first point."""
    lin = m[:3, :3]
    scales = np.linalg.norm(lin, axis=1)
    scale = float(abs(np.linalg.det(lin))) ** (1.0 / 3.0)
    if scales.max() > 1.01 * scales.min():
        note("BasisCurves under a non-uniform scale keep round sections (widths scaled by the mean scale)")
    pts, segs, flags, base = [], [], [], 0
    for path, w, periodic in paths:
        if periodic:
            path, w = np.vstack([path, path[:1]]), np.concatenate([w, w[:1]])
        k = len(path)
        world = path @ lin + m[3, :3]
        pts.append(np.column_stack([world, 0.5 * w * scale]))
        n = k - 1
        segs.append(base + np.arange(n))
        f = np.zeros(n, np.uint8)
        f[1:] |= 1   # RTC_CURVE_FLAG_NEIGHBOR_LEFT
        f[:-1] |= 2  # RTC_CURVE_FLAG_NEIGHBOR_RIGHT
        flags.append(f)
        base += k
    return np.vstack(pts), np.concatenate(segs).astype(np.uint32), np.concatenate(flags)
