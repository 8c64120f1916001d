"""Absorbing interiors of transmissive surfaces -> homogeneous media bound to closed meshes
(docs/media.md, "Absorbing glass"): whether a mesh's faces close a volume, which side of
them is inside, and the media and per-material interface tables the core reads."""
from __future__ import annotations

import math

import numpy as np

# Transmission colours are clamped to this before the logarithm: a black channel absorbs
# everything within a few depths (e^-13.8 = 1e-6 per depth) instead of an infinite sigma_a.
MIN_TRANSMISSION_COLOR = 1e-6


def absorption(color: tuple[float, float, float], depth: float) -> tuple[float, float, float]:
    """sigma_a per channel (per scene unit) from a transmission colour c and depth d > 0:
    light travelling d inside keeps c, so e^(-sigma_a d) = c and sigma_a = -ln(c) / d."""
    return tuple(-math.log(min(max(float(c), MIN_TRANSMISSION_COLOR), 1.0)) / depth for c in color)


def closed_orientation(points: np.ndarray, tris: np.ndarray) -> int:
    """+1 when the triangles close a volume with their normals (counter-clockwise winding)
    outward, -1 when closed and wound inward, 0 when open or not consistently wound.
    Vertices are welded by position first (meshes split at UV or normal seams are closed
    all the same) and triangles with a repeated vertex dropped (a sphere's poles)."""
    if len(tris) < 4:
        return 0
    _, weld = np.unique(np.asarray(points, np.float64), axis=0, return_inverse=True)
    t = weld.reshape(-1)[np.asarray(tris, np.int64)]
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])]
    if len(t) < 4:
        return 0
    n = int(t.max()) + 1
    a = t.reshape(-1)
    b = np.roll(t, -1, axis=1).reshape(-1)
    forward, backward = np.sort(a * n + b), np.sort(b * n + a)
    # Closed and consistently wound: every directed edge once, and its reverse once.
    if np.any(forward[1:] == forward[:-1]) or not np.array_equal(forward, backward):
        return 0
    p = np.asarray(points, np.float64)[np.asarray(tris, np.int64)]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return 0 if volume == 0.0 else (1 if volume > 0.0 else -1)


def media_tables(rows: list[dict], used: set[int]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(media float32 (K, 7): sigma_a rgb, sigma_s rgb, g; material_media int32 (M, 2):
    inside, outside) for the `used` material rows whose "interior" holds an absorption, or
    (None, None) when none has one (a row an open mesh left for its tinted copy is unused).
    Equal absorptions share a medium."""
    media: dict[tuple, int] = {}
    table = np.full((len(rows), 2), -1, np.int32)
    for m, row in enumerate(rows):
        sigma_a = row.get("interior")
        if sigma_a is None or m not in used:
            continue
        k = media.setdefault(tuple(sigma_a), len(media))
        table[m, 0 if row.get("medium_side", "inside") == "inside" else 1] = k
    if not media:
        return None, None
    return np.array([[*s, 0.0, 0.0, 0.0, 0.0] for s in media], np.float32).reshape(-1, 7), table
