"""A scene's size from what it declares, before any geometry is built.

The translator materialises points, indices, normals and texture coordinates and
triangulates them: about 300 bytes per triangle at its peak. A 160 KB .usdc whose
compressed arrays declare 20 million triangles drove each pre-flight to 6 GB for half a
minute before the triangle limit or the memory limit stopped it. The census reads, per
mesh, only `faceVertexCounts` (4 bytes a face, the smallest array that fixes the triangle
count: a face of n vertices gives n - 2), and per point instancer nothing at all, and
refuses a scene over the limits before the translator starts. usd-core has no API that
reports an array's length without reading it (Sdf and Usd both hand back the whole
VtArray), so this is the cheapest exact count; the pre-flight also runs the census under
a tighter address-space limit (inspect.py), so that a counts array too large to hold is
itself a quick refusal.

The count is of the triangles the translator stores: every mesh once, a native-instance
prototype or point-instancer prototype once however often it is instanced (instances
cost a transform each, not a copy). Invisible, guide and proxy subtrees are skipped as the
translator skips them. Holes are not subtracted (the census may only over-count).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bundle import Limits
from .gprims import NURBS_SEGMENTS, POINT_SPHERE_TRIANGLES, RINGS, SEGMENTS
from .errors import SceneError

# Upper bound of the triangles one tessellated Sphere, Cube, Cylinder, Cone, Capsule or
# Plane becomes (gprims.py: SEGMENTS x RINGS quads at most).
GPRIM_TRIANGLES = 2 * SEGMENTS * (RINGS + 2)
_GPRIMS = ("Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane")


@dataclass
class Census:
    triangles: int = 0
    faces: int = 0
    meshes: int = 0
    prims: int = 0
    largest_mesh: str = ""
    largest_triangles: int = 0


def take_census(stage, limits: Limits, time=None) -> Census:
    """Counts what the stage declares; SceneError as soon as a limit is exceeded."""
    from pxr import Usd, UsdGeom

    time = Usd.TimeCode.Default() if time is None else time
    census = Census()
    roots = [Usd.PrimRange.Stage(stage, Usd.PrimDefaultPredicate)]
    roots += [Usd.PrimRange(p, Usd.PrimDefaultPredicate) for p in stage.GetPrototypes()]
    for prim_range in roots:
        it = iter(prim_range)
        for prim in it:
            census.prims += 1
            if census.prims > limits.prims:
                raise SceneError(f"the scene has more than {limits.prims} prims (limit)")
            imageable = UsdGeom.Imageable(prim)
            if imageable and (imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible or
                              imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)):
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.Mesh):
                _count_mesh(census, UsdGeom.Mesh(prim), time, limits)
            elif prim.GetTypeName() in _GPRIMS:
                _add(census, GPRIM_TRIANGLES, str(prim.GetPath()), limits)
            elif prim.IsA(UsdGeom.Points):
                _add(census, POINT_SPHERE_TRIANGLES * _length(UsdGeom.Points(prim).GetPointsAttr(), time),
                     str(prim.GetPath()), limits)
            elif prim.IsA(UsdGeom.NurbsPatch):
                patch = UsdGeom.NurbsPatch(prim)
                # At most NURBS_SEGMENTS pieces per knot span and direction (gprims.nurbs_patch).
                spans = [max(_length(a, time) - 1, 1) for a in (patch.GetUKnotsAttr(), patch.GetVKnotsAttr())]
                _add(census, 2 * NURBS_SEGMENTS ** 2 * spans[0] * spans[1], str(prim.GetPath()), limits)
    return census


def _length(attr, time) -> int:
    """An array attribute's length (a value that is not an array counts as empty: the
    translator warns)."""
    value = attr.Get(time)
    try:
        return len(value) if value is not None else 0
    except TypeError:
        return 0


def _count_mesh(census: Census, mesh, time, limits: Limits) -> None:
    from pxr import Tf

    path = str(mesh.GetPath())
    try:
        counts = mesh.GetFaceVertexCountsAttr().Get(time)
    except (Tf.ErrorException, MemoryError):
        # usd-core reports an allocation that failed under the census's memory limit as a
        # corrupt value; either way the scene cannot be inspected.
        raise SceneError(f"{path}: faceVertexCounts cannot be read within the pre-flight's "
                         f"memory (corrupt, or far more faces than the limit of "
                         f"{limits.triangles} triangles)") from None
    if counts is None:
        return  # the translator skips it with a warning
    try:
        counts = np.asarray(counts)
    except (TypeError, ValueError):
        return  # the wrong type: the translator warns
    if counts.dtype.kind not in "iu" or counts.ndim != 1:
        return
    census.meshes += 1
    census.faces += len(counts)
    if len(counts) > limits.triangles:
        # Every face of 3 or more vertices is at least one triangle; faces of fewer are
        # skipped, but a mesh of more faces than the whole scene may have triangles is no
        # scene anyone means to render.
        raise SceneError(f"{path}: the mesh has {len(counts)} faces, more than the scene's "
                         f"limit of {limits.triangles} triangles")
    # sum(max(c - 2, 0)) without an int64 copy of the array: faces of fewer than 3
    # vertices (rare) are corrected for separately.
    small = counts[counts < 2].astype(np.int64)
    triangles = int(counts.sum(dtype=np.int64)) - 2 * len(counts) + int((2 - small).sum())
    _add(census, triangles, path, limits)


def _add(census: Census, triangles: int, path: str, limits: Limits) -> None:
    census.triangles += triangles
    if triangles > census.largest_triangles:
        census.largest_mesh, census.largest_triangles = path, triangles
    if census.triangles > limits.triangles:
        raise SceneError(f"the scene declares more than {limits.triangles} triangles (limit): "
                         f"at least {census.triangles}, {census.largest_triangles} of them in "
                         f"{census.largest_mesh}")
