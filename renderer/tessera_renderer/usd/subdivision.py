"""UsdGeom subdivision surfaces refined into triangles (OpenSubdiv, through the core's
`_subdivision` module) at translation time, so the renderer only ever meets triangles.

Uniform refinement `level` times, vertices moved to the limit surface, normals from the
limit tangents; creases, corners, holes, interpolateBoundary and triangleSubdivisionRule
are honoured. Face-varying primvars (UVs) are interpolated bilinearly inside each cage
face (OpenSubdiv's "linear all"), whatever faceVaryingLinearInterpolation says.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

# Default uniform refinement level: each level splits a quad into four, so level 2 gives
# 32 triangles per cage quad; enough for a smooth silhouette at film resolutions on the
# cages real exporters write, cheap enough for meshes with tens of thousands of faces.
DEFAULT_LEVEL = 2
MAX_LEVEL = 6
# A mesh is refined less (with a note) when its refined triangles would pass this share of
# the job's triangle limit.
MESH_SHARE_OF_TRIANGLE_LIMIT = 4

SCHEMES = {"catmullClark": 0, "loop": 1, "bilinear": 2}
BOUNDARIES = {"none": 0, "edgeOnly": 1, "edgeAndCorner": 2}


@dataclass
class RefinedMesh:
    points: np.ndarray       # (V, 3) limit positions
    tris: np.ndarray         # (T, 3)
    face_of_tri: np.ndarray  # (T,) cage face of each triangle
    normals: np.ndarray      # (T, 3, 3) limit normals per corner
    surface: object          # the core's SubdivisionSurface, for face-varying data
    order: np.ndarray        # cage corner (faceVertexIndices position) per OpenSubdiv slot
    level: int
    # Limit positions (V, 3) of the same cage with other points (a deforming mesh's steps):
    # the same topology and rules, so the same vertices in the same order.
    limit_points: Callable[[np.ndarray], np.ndarray]

    def face_varying(self, per_corner: np.ndarray) -> np.ndarray:
        """(C, w) values per faceVertexIndices entry -> (T, 3, w) per triangle corner."""
        w = per_corner.shape[1]
        values = np.ascontiguousarray(per_corner[self.order], dtype=np.float32)
        return np.asarray(self.surface.refine_face_varying(values, w)).reshape(-1, 3, w)


def refined_triangles(n_quads: int, n_tris: int, scheme: str, level: int) -> int:
    """Triangles uniform refinement makes: Catmull-Clark turns an n-gon into n quads, then
    each quad into four per level; Loop splits each triangle into four per level."""
    if scheme == "loop":
        return n_tris * 4 ** level
    return 2 * n_quads * 4 ** (level - 1) if level >= 1 else n_quads


def creases(mesh, time, n_points: int, note):
    """(edges (E, 2), sharpness (E,)) from creaseIndices/Lengths/Sharpnesses; sharpness is
    per crease or per edge as the schema allows. Malformed creases are ignored with a note."""
    idx = mesh.GetCreaseIndicesAttr().Get(time)
    lengths = mesh.GetCreaseLengthsAttr().Get(time)
    sharp = mesh.GetCreaseSharpnessesAttr().Get(time)
    empty = (np.zeros((0, 2), np.int32), np.zeros(0, np.float32))
    if not idx or not lengths or not sharp:
        return empty
    idx, lengths, sharp = (np.asarray(idx, np.int64), np.asarray(lengths, np.int64),
                           np.asarray(sharp, np.float32))
    if lengths.min() < 2 or lengths.sum() != len(idx) or idx.min() < 0 or idx.max() >= n_points:
        note("subdivision creases whose creaseIndices and creaseLengths disagree are ignored")
        return empty
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    a = np.concatenate([np.arange(s, s + n - 1) for s, n in zip(starts, lengths)])
    edges = np.stack([idx[a], idx[a + 1]], -1)
    if len(sharp) == len(lengths):
        per_edge = np.repeat(sharp, lengths - 1)
    elif len(sharp) == len(edges):
        per_edge = sharp
    else:
        note("subdivision creases with a creaseSharpnesses count that is neither per crease nor "
             "per edge are ignored")
        return empty
    return edges.astype(np.int32), per_edge.astype(np.float32)


def refine(mesh, time, points, counts, face_indices, left_handed: bool, level: int, holes, note):
    """The refined mesh, or None (with a note) when the cage cannot be subdivided as
    authored; the caller then renders the cage."""
    from pxr import UsdGeom

    from .. import _subdivision

    scheme = str(mesh.GetSubdivisionSchemeAttr().Get(time))
    if scheme not in SCHEMES:
        note(f"subdivision scheme {scheme!r} is unknown; such meshes render as their cage")
        return None
    if np.any(counts < 3):
        note("subdivision meshes with faces of fewer than 3 vertices render as their cage")
        return None
    if scheme == "loop" and np.any(counts != 3):
        note("loop subdivision meshes with non-triangle faces render as their cage (Loop needs triangles)")
        return None
    # OpenSubdiv assumes counter-clockwise faces: reverse each face of a leftHanded mesh.
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    order = np.arange(len(face_indices))
    if left_handed:
        order = np.concatenate([s + np.arange(n)[::-1] for s, n in zip(starts, counts)])
    edges, sharpness = creases(mesh, time, len(points), note)
    corner_idx = mesh.GetCornerIndicesAttr().Get(time)
    corner_sharp = mesh.GetCornerSharpnessesAttr().Get(time)
    corner_idx = np.asarray(corner_idx if corner_idx else [], np.int32)
    corner_sharp = np.asarray(corner_sharp if corner_sharp else [], np.float32)
    if len(corner_idx) != len(corner_sharp) or (len(corner_idx) and (
            corner_idx.min() < 0 or corner_idx.max() >= len(points))):
        note("subdivision corners whose cornerIndices and cornerSharpnesses disagree are ignored")
        corner_idx, corner_sharp = np.zeros(0, np.int32), np.zeros(0, np.float32)
    boundary = str(mesh.GetInterpolateBoundaryAttr().Get(time) or "edgeAndCorner")
    rule = mesh.GetTriangleSubdivisionRuleAttr().Get(time)
    def surface_of(cage_points):
        return _subdivision.SubdivisionSurface(
            np.ascontiguousarray(cage_points, np.float32), np.ascontiguousarray(counts, np.int32),
            np.ascontiguousarray(face_indices[order], np.int32), int(level), SCHEMES[scheme],
            BOUNDARIES.get(boundary, 2), rule == UsdGeom.Tokens.smooth,
            np.ascontiguousarray(edges.reshape(-1)), sharpness, corner_idx, corner_sharp,
            np.asarray(holes, np.int32))

    try:
        surface = surface_of(points)
    except ValueError as err:
        note(f"subdivision meshes OpenSubdiv cannot refine ({err}) render as their cage")
        return None
    pts = np.asarray(surface.points(), np.float64)
    tris = np.asarray(surface.triangles(), np.int64)
    normals = np.asarray(surface.normals(), np.float32)[tris]
    return RefinedMesh(pts, tris, np.asarray(surface.parent_faces(), np.int64), normals, surface, order, level,
                       lambda cage_points: np.asarray(surface_of(cage_points).points(), np.float64))
