"""Screen-space dicing: the subdivision level of each subdivision mesh chosen from how large
its cage looks in the rendering camera, then lowered, largest meshes first, until the
estimated memory of the refined triangles fits a budget (docs/scene-translation.md,
"Subdivision surfaces").

A uniform level everywhere spends most triangles where they are invisible (a distant
asset of 400k cage quads became 12.8 M stored triangles at level 2); production
renderers dice to a rate in pixels instead (Cycles' dicing rate, RenderMan's micropolygon
length). Each Catmull-Clark or Loop level halves every edge, so a cage whose longest
projected edge is E pixels needs ceil(log2(E / rate)) levels for its micro-edges to be at
most `rate` pixels long. The longest edge is taken over every cage edge in front of the
camera, on screen or not: conservative, and a function of the stage, the camera and the
resolution only, so every worker of a farm job that translates the same inputs gets the
same levels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import subdivision

# Bytes one stored refined triangle costs at peak, used to hold the refined meshes to the
# memory budget: the translated arrays are ~58 B (positions, indices, per-corner normals,
# material; UVs add 24), the rest is OpenSubdiv's refinement, the core's copy and Embree's
# BVH. Measured as the growth of a process's peak RSS per extra stored triangle, 246 and
# 297 B (docs/benchmarks/dicing.md): about the larger, so the budget is not passed.
BYTES_PER_TRIANGLE = 300


@dataclass(frozen=True)
class Dicing:
    """How subdivision levels are chosen when no fixed level is asked for. `rate`: the
    longest micro-edge wanted, in pixels; `max_level`: no mesh is refined more (and at
    least once, the coarsest refinement that puts vertices on the limit surface);
    `memory_mb`: the refined triangles' estimated memory (BYTES_PER_TRIANGLE each) is
    held under this by lowering levels; `resolution`: the image's (width, height) the
    rate is measured in (None: the stage's RenderSettings', else the default)."""
    rate: float = 1.0
    max_level: int = 4
    memory_mb: float = 1024.0
    resolution: tuple[int, int] | None = None

    def __post_init__(self):
        from .errors import SceneError

        if not (isinstance(self.rate, (int, float)) and math.isfinite(self.rate) and self.rate > 0):
            raise SceneError(f"dicing rate must be a positive number of pixels, not {self.rate!r}")
        if not (isinstance(self.max_level, int) and 1 <= self.max_level <= subdivision.MAX_LEVEL):
            raise SceneError(f"dicing maximum level must be an integer from 1 to {subdivision.MAX_LEVEL}, "
                             f"not {self.max_level!r}")
        if not (isinstance(self.memory_mb, (int, float)) and self.memory_mb > 0):
            raise SceneError(f"dicing memory budget must be a positive number of MB, not {self.memory_mb!r}")
        if self.resolution is not None and (len(self.resolution) != 2 or min(self.resolution) < 1):
            raise SceneError(f"dicing resolution must be (width, height) in pixels, not {self.resolution!r}")


    @classmethod
    def requested(cls, rate: float | None, max_level: int | None = None, memory_mb: float | None = None,
                  resolution: tuple[int, int] | None = None) -> "Dicing | None":
        """The Dicing the render settings dicing_rate, dicing_max_level and dicing_memory
        ask for (None: that setting's default), at `resolution`; None without a rate."""
        if rate is None:
            return None
        given = dict(max_level=max_level, memory_mb=memory_mb)
        return cls(rate=rate, resolution=None if resolution is None else tuple(resolution),
                   **{k: v for k, v in given.items() if v is not None})

    @classmethod
    def from_json(cls, value: dict) -> "Dicing":
        """The Dicing of tessera_base.protocol.dicing_of's answer (a farm job's request, as
        the worker hands it to its render process and the pre-flight to its inspection)."""
        return cls.requested(value["rate"], value.get("max_level"), value.get("memory_mb"),
                             value.get("resolution"))


def pixel_size(camera, resolution: tuple[int, int]) -> float:
    """Width of one pixel: at unit depth for a perspective camera, in scene units for an
    orthographic one (the window is fitted to the image's aspect, so pixels are square)."""
    half_w, _, _, _ = camera.window(*resolution)
    return 2.0 * half_w / resolution[0]


def longest_projected_edge(world_points: np.ndarray, counts: np.ndarray, face_indices: np.ndarray,
                           camera, resolution: tuple[int, int]) -> float:
    """The longest cage edge in pixels, each edge measured at its nearer end's depth (not
    nearer than the near clipping plane); edges wholly behind the camera do not count."""
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    within = np.arange(len(face_indices)) - starts
    nxt = starts + (within + 1) % np.repeat(counts, counts)
    a, b = world_points[face_indices], world_points[face_indices[nxt]]
    length = np.linalg.norm(a - b, axis=1)
    px = pixel_size(camera, resolution)
    if camera.orthographic:
        return float(length.max(initial=0.0) / px)
    origin, forward = np.asarray(camera.origin, np.float64), np.asarray(camera.forward, np.float64)
    forward = forward / np.linalg.norm(forward)
    depth_a, depth_b = (a - origin) @ forward, (b - origin) @ forward
    front = (depth_a > 0) | (depth_b > 0)
    if not front.any():
        return 0.0
    nearest = np.where(depth_a > 0, depth_a, np.inf)
    nearest = np.minimum(nearest, np.where(depth_b > 0, depth_b, np.inf))[front]
    nearest = np.maximum(nearest, max(camera.clip_near, 1e-9))
    return float((length[front] / (nearest * px)).max())


def level_for(projected_edge: float, dicing: Dicing) -> int:
    """Levels needed for micro-edges of at most `dicing.rate` pixels, within [1, max_level]."""
    if projected_edge <= dicing.rate:
        return 1
    return int(min(dicing.max_level, max(1, math.ceil(math.log2(projected_edge / dicing.rate)))))


def plan(stage, time, xform_cache, camera, dicing: Dicing, resolution, instancing: str, note) -> dict[str, int]:
    """Subdivision level per mesh path (the prototype's path for native instances when they
    are kept as instances), from the projected cage, then held to the memory budget."""
    from pxr import Usd, UsdGeom

    meshes: dict[str, list] = {}  # path -> [quads, triangles, scheme, level]
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        imageable = UsdGeom.Imageable(prim)
        if imageable and imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            it.PruneChildren()
            continue
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        scheme = str(mesh.GetSubdivisionSchemeAttr().Get(time))
        if scheme not in subdivision.SCHEMES:
            continue
        points, counts = mesh.GetPointsAttr().Get(time), mesh.GetFaceVertexCountsAttr().Get(time)
        face_indices = mesh.GetFaceVertexIndicesAttr().Get(time)
        if not points or not counts or not face_indices:
            continue  # the walk names what is wrong with it
        points = np.asarray(points, np.float64).reshape(-1, 3)
        counts, face_indices = np.asarray(counts, np.int64), np.asarray(face_indices, np.int64)
        if counts.min() < 3 or counts.sum() != len(face_indices) or face_indices.min() < 0 \
                or face_indices.max() >= len(points):
            continue
        m = np.asarray(xform_cache.GetLocalToWorldTransform(prim), np.float64)
        world = points @ m[:3, :3] + m[3, :3]
        level = level_for(longest_projected_edge(world, counts, face_indices, camera, resolution), dicing)
        path = str(prim.GetPath())
        if prim.IsInstanceProxy() and instancing != "flatten":
            path = str(prim.GetPrimInPrototype().GetPath())
        quads = int(counts.sum()) if scheme != "loop" else 0
        if path in meshes:  # a prototype seen through several instances: the nearest decides
            meshes[path][3] = max(meshes[path][3], level)
        else:
            meshes[path] = [quads, len(counts), scheme, level]

    def triangles(entry) -> int:
        return subdivision.refined_triangles(entry[0], entry[1], entry[2], entry[3])

    budget = dicing.memory_mb * 2 ** 20 / BYTES_PER_TRIANGLE
    total = sum(triangles(e) for e in meshes.values())
    lowered = 0
    while total > budget:
        # The mesh with the most refined triangles gives up a level (ties: by path, so
        # the choice never depends on traversal order).
        candidates = [(triangles(e), p) for p, e in meshes.items() if e[3] > 1]
        if not candidates:
            note(f"subdivision surfaces exceed the {dicing.memory_mb:g} MB dicing memory budget even "
                 f"refined once each")
            break
        _, path = max(candidates)
        total -= triangles(meshes[path])
        meshes[path][3] -= 1
        total += triangles(meshes[path])
        lowered += 1
    if lowered:
        note(f"subdivision levels lowered by {lowered} in all (largest meshes first) to fit the "
             f"{dicing.memory_mb:g} MB dicing memory budget")
    return {p: e[3] for p, e in meshes.items()}
