"""USD stage -> flat arrays for the C++ core.

Reads a composed stage with `pxr` (usd-core) and produces world-space triangles, a material
table (UsdPreviewSurface parameters and a texture table), lights of every UsdLux kind the
core knows, a camera and a resolution. Mesh work is vectorised with numpy: Python loops run
per prim, per GeomSubset or per prototype, never per vertex or per instance.

Conventions (documented in docs/scene-translation.md):
- Light radiance = color * intensity * 2^exposure (* blackbody(colorTemperature) when
  enabled), divided by the light's world-space area when `normalize` is on: intensity 1
  seen head-on gives pixel value 1 (NVIDIA's UsdLux clarification).
- RectLight and DiskLight are centred in local XY and emit along local -Z, one-sided;
  CylinderLight lies along local X and emits outward from its side only.
- Emissive meshes emit on the side their winding faces; on both sides when `doubleSided`.
- Camera apertures and focal length share a unit, so only their ratio matters; the aperture
  is expanded to the image's aspect ratio (UsdRenderSettings' default conform policy).
"""
from __future__ import annotations

import json
import math
from collections import Counter
import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import curves, gprims, light_shaping, subdivision


class SceneError(Exception):
    """The scene cannot be rendered; the message says why, for the person who sent it."""


DEFAULT_RESOLUTION = (512, 512)
# Flattening more instanced triangles than this warns: the core then holds every copy.
FLATTEN_WARN_TRIANGLES = 5_000_000

# Prim types that carry no geometry of their own: traversed without a warning.
_STRUCTURAL_TYPES = {
    "", "Xform", "Scope", "Material", "Shader", "NodeGraph", "GeomSubset", "Camera",
    "RenderSettings", "RenderProduct", "RenderVar", "RenderPass", "Mesh", "RectLight",
    "SphereLight", "DiskLight", "CylinderLight", "DistantLight", "DomeLight", "PointInstancer",
    "Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane",
    # UsdSkel: the skeleton deforms the meshes under its SkelRoot (see _Translator.skin).
    "SkelRoot", "Skeleton", "SkelAnimation", "BlendShape",
}
_GPRIMS = ("Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane")
# UV sets read when no UsdPrimvarReader_float2 names one: the common names of DCC exporters
# (USD's st, Blender's UVMap, Maya's map1, ...), first found wins.
DEFAULT_UV_SETS = ("st", "st0", "UVMap", "uv", "map1")

# UsdPreviewSurface inputs carried per material row, with the SceneData key they fill.
_SCALAR_INPUTS = {"metallic": "metallic", "roughness": "roughness", "ior": "ior",
                  "clearcoat": "clearcoat", "clearcoatRoughness": "clearcoat_roughness",
                  "opacity": "opacity", "opacityThreshold": "opacity_threshold",
                  "useSpecularWorkflow": "use_specular_workflow"}
_COLOR_INPUTS = ("diffuseColor", "emissiveColor", "specularColor")
# opacity_threshold of a row whose opacity is presence (see _Translator._is_presence): a
# value USD cannot author (the threshold is >= 0), read by the core as "a hit is a surface
# with probability opacity, else passed straight through".
PRESENCE_MODE = -1.0
PARAM_KEYS = ("specular_color",) + tuple(_SCALAR_INPUTS.values()) + ("preview_surface",)


@dataclass
class CameraDesc:
    origin: tuple[float, float, float]
    right: tuple[float, float, float]
    up: tuple[float, float, float]
    forward: tuple[float, float, float]
    horizontal_aperture: float   # same unit as focal_length; only ratios matter
    vertical_aperture: float
    focal_length: float
    source: str                  # prim path, or a description of the default camera
    # Thin lens (scene units): radius = focal length / (2 fStop), 0 for a pinhole
    # (fStop 0); the focus plane's distance; primary visibility clipped to [near, far].
    lens_radius: float = 0.0
    focus_distance: float = 1.0
    clip_near: float = 0.0
    clip_far: float = math.inf

    def tan_half_angles(self, width: int, height: int) -> tuple[float, float]:
        """Fits the aperture to the image by expanding it (never cropping)."""
        tan_w = self.horizontal_aperture / (2.0 * self.focal_length)
        tan_h = self.vertical_aperture / (2.0 * self.focal_length)
        image_aspect = width / height
        if image_aspect >= tan_w / tan_h:
            tan_w = tan_h * image_aspect
        else:
            tan_h = tan_w / image_aspect
        return tan_w, tan_h


@dataclass
class SceneData:
    """Everything the core needs, as plain arrays. Fields after `warnings` are read by the
    core as it grows; the binding reads only what it knows."""

    positions: np.ndarray           # float32 (V, 3), world space
    indices: np.ndarray             # uint32 (T, 3)
    triangle_material: np.ndarray   # uint32 (T,)
    albedo: np.ndarray              # float32 (M, 3)  diffuseColor clamped to [0, 1]
    emission: np.ndarray            # float32 (M, 3)  emitted radiance
    two_sided_emission: np.ndarray  # bool (M,)
    sphere_lights: np.ndarray       # float32 (S, 7): centre, radius, radiance
    camera: CameraDesc
    resolution: tuple[int, int]
    resolution_from_stage: bool
    warnings: list[str] = field(default_factory=list)
    material_params: dict[str, np.ndarray] = field(default_factory=dict)  # per row, see PARAM_KEYS
    shading_normals: np.ndarray | None = None   # float32 (T, 3, 3) world, per corner
    uvs: np.ndarray | None = None               # float32 (T, 3, 2) per corner st
    textures: list[dict] = field(default_factory=list)
    material_textures: dict[tuple[int, str], int] = field(default_factory=dict)
    distant_lights: np.ndarray = field(default_factory=lambda: np.zeros((0, 7), np.float32))
    point_lights: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.float32))
    dome_light: dict | None = None
    prototypes: list[dict] = field(default_factory=list)
    instances: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))
    instance_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float32))
    meters_per_unit: float = 0.01
    up_axis: str = "Y"
    # The world-space position of this data's origin: a translated stage is moved so that
    # its camera sits at the origin (float32 precision follows distance from the camera);
    # world = these coordinates + world_offset.
    world_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Lights for a stage that has none (see default_lighting), not yet part of the light
    # tables above; Scene adds them unless default lighting is switched off. None when the
    # stage has a light (emissive geometry counts) or they were applied already.
    default_lights: dict | None = None


@dataclass
class _Chunk:
    """Triangles of one prim in some space: points (V,3) f64, tris (T,3) int, per-triangle
    material rows, optional per-corner normals (T,3,3) and st (T,3,2)."""

    points: np.ndarray
    tris: np.ndarray
    material: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None

    def transformed(self, m: np.ndarray) -> "_Chunk":
        """The chunk in another space. Normals are left unnormalised (emit normalises)."""
        linear = m[:3, :3]
        identity = np.array_equal(linear, np.eye(3))
        pts = self.points if identity else self.points @ linear
        if m[3, :3].any():
            pts = pts + m[3, :3]
        tris, normals, uvs = self.tris, self.normals, self.uvs
        if normals is not None and not identity:
            # Normals transform by the inverse transpose; row vectors: n @ inv(M3).T
            det = np.linalg.det(linear)
            nm = np.linalg.inv(linear).T if abs(det) > 1e-300 else linear
            normals = normals @ nm.astype(normals.dtype)
        if np.linalg.det(linear) < 0:  # a mirroring transform flips the winding
            tris = tris[:, ::-1]
            normals = normals[:, ::-1] if normals is not None else None
            uvs = uvs[:, ::-1] if uvs is not None else None
        return _Chunk(pts, tris, self.material, normals, uvs)


class _MaterialTable:
    """Deduplicates material rows: every parameter, texture binding and the two-sidedness."""

    def __init__(self) -> None:
        self.rows: list[dict] = []
        self._index: dict[Any, int] = {}
        self.textures: list[dict] = []
        self._tex_index: dict[Any, int] = {}

    def add_texture(self, tex: dict) -> int:
        # JSON text as the key: values include lists and the UsdTransform2d dict.
        key = json.dumps(tex, sort_keys=True, default=str)
        if key not in self._tex_index:
            self._tex_index[key] = len(self.textures)
            self.textures.append(tex)
        return self._tex_index[key]

    def add(self, surface: dict, two_sided: bool) -> int:
        preview = bool(surface.get("preview", False))
        key = (tuple(sorted((k, v) for k, v in surface["values"].items())),
               tuple(sorted(surface["textures"].items())), bool(two_sided), preview)
        if key not in self._index:
            self._index[key] = len(self.rows)
            self.rows.append({"values": surface["values"], "textures": surface["textures"],
                              "two_sided": bool(two_sided), "preview": preview})
        return self._index[key]


class _Translator:
    def __init__(self, stage, time, warn, bundle, limits, instancing: str,
                 subdivision_level: int = subdivision.DEFAULT_LEVEL):
        from pxr import Sdr, UsdGeom

        self.stage = stage
        self.subdivision_level = subdivision_level
        self.subdivided_meshes = 0
        self.time = time
        self.warn = warn
        self.bundle = bundle
        self.limits = limits
        self.instancing = instancing
        self.xform_cache = UsdGeom.XformCache(time)
        self.materials = _MaterialTable()
        self.chunks: list[_Chunk] = []
        self.sphere_lights: list[list[float]] = []
        self.point_lights: list[list[float]] = []
        self.distant_lights: list[list[float]] = []
        self.dome_light: dict | None = None
        self.prototypes: list[dict] = []
        self._proto_index: dict[str, int] = {}
        self.instances: list[np.ndarray] = []
        self.instance_xforms: list[np.ndarray] = []
        self.triangles = 0
        self.instanced_triangles = 0
        # Lights met inside native-instance prototypes: flattening renders them (instance
        # proxies are walked as top-level prims), instancing cannot; "auto" then flattens.
        self.native_prototype_lights = 0
        self._in_native_prototype = False
        self.prims = 0
        self.cameras: list = []
        self.unsupported: Counter = Counter()
        self._surface_cache: dict[Any, dict] = {}
        self._geometry_cache: dict[str, Any] = {}
        self._notes: Counter = Counter()  # repeated warnings, reported once with a count
        # Skinned meshes: prim path -> (points in skeleton space at the frame, the
        # skeleton's local-to-world matrix). Filled by skin() before the walk.
        self.skinned: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        # Materials rendered with the default grey: path -> their shader id or why.
        self.grey_materials: dict[str, str] = {}
        node = Sdr.Registry().GetShaderNodeByIdentifier("UsdPreviewSurface")
        # UsdPreviewSurface defaults come from its registered definition, not from here.
        self.defaults = {name: _as_tuple(node.GetShaderInput(name).GetDefaultValue())
                         for name in _COLOR_INPUTS + tuple(_SCALAR_INPUTS)}
        self.default_diffuse = self.defaults["diffuseColor"]
        tex = Sdr.Registry().GetShaderNodeByIdentifier("UsdUVTexture")
        self.tex_defaults = {n: tex.GetShaderInput(n).GetDefaultValue() for n in ("scale", "bias", "fallback")}

    # -- traversal ------------------------------------------------------------------
    def world_matrix(self, prim) -> np.ndarray:
        """4x4 float64, USD's row-vector convention: p_world = [p, 1] @ M."""
        return np.array(self.xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64)

    def walk(self, root_range, base_inv: np.ndarray | None, sink: list, top_level: bool) -> None:
        """Translates every renderable prim of a prim range into `sink` as chunks in the
        space `world @ base_inv` (world space when base_inv is None)."""
        from pxr import UsdGeom, UsdLux

        it = iter(root_range)
        for prim in it:
            self.prims += 1
            if self.prims > self.limits.prims:
                raise SceneError(f"the scene has more than {self.limits.prims} prims (limit)")
            imageable = UsdGeom.Imageable(prim)
            if imageable:
                if imageable.ComputeVisibility(self.time) == UsdGeom.Tokens.invisible or \
                        imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                    it.PruneChildren()
                    continue
            if self.instancing == "instances" and prim.IsInstance() and top_level:
                self.add_native_instance(prim)
                it.PruneChildren()
                continue
            type_name = prim.GetTypeName()
            if prim.IsA(UsdGeom.PointInstancer):
                self.add_point_instancer(prim, base_inv, sink, top_level)
                it.PruneChildren()  # prototypes render only through the instancer
                continue
            m = self.world_matrix(prim) if (prim.IsA(UsdGeom.Gprim)) else None
            skinned = self.skinned.get(str(prim.GetPath())) if self.skinned else None
            if skinned is not None:
                m = skinned[1]  # skinned points are in the skeleton's space
            if m is not None and base_inv is not None:
                m = m @ base_inv
            if prim.IsA(UsdGeom.Mesh):
                chunk = self.mesh_chunk(prim)
                if chunk is not None:
                    self.emit(chunk.transformed(m), sink, str(prim.GetPath()))
            elif type_name in _GPRIMS:
                chunk = self.gprim_chunk(prim, type_name)
                if chunk is not None:
                    self.emit(chunk.transformed(m), sink, str(prim.GetPath()))
            elif prim.IsA(UsdGeom.BasisCurves):
                chunk = self.curves_chunk(prim)
                if chunk is not None:
                    self.emit(chunk.transformed(m), sink, str(prim.GetPath()))
            elif prim.HasAPI(UsdLux.LightAPI) or prim.IsA(UsdLux.BoundableLightBase) or \
                    prim.IsA(UsdLux.NonboundableLightBase):
                if not top_level:
                    self._count_note("lights inside instance prototypes are not supported; skipped")
                    self.native_prototype_lights += int(self._in_native_prototype)
                else:
                    self.add_light(prim, type_name)
            elif prim.IsA(UsdGeom.Camera):
                if top_level:
                    self.cameras.append(prim)
            elif type_name not in _STRUCTURAL_TYPES:
                if prim.IsA(UsdGeom.Gprim):
                    self.unsupported[type_name] += 1
                elif type_name and not prim.IsA(UsdGeom.Imageable):
                    pass  # non-imageable typed prims (e.g. materials of other renderers)
                else:
                    self.unsupported[type_name] += 1

    def emit(self, chunk: _Chunk, sink: list, path: str) -> None:
        bad_vertex = ~np.isfinite(chunk.points).all(axis=1)
        if bad_vertex.any():
            keep = ~bad_vertex[chunk.tris].any(axis=1)
            self.warn(f"{path}: {int((~keep).sum())} triangles with NaN/Inf vertices skipped")
            chunk = _Chunk(np.where(bad_vertex[:, None], 0.0, chunk.points), chunk.tris[keep],
                           chunk.material[keep],
                           chunk.normals[keep] if chunk.normals is not None else None,
                           chunk.uvs[keep] if chunk.uvs is not None else None)
        if chunk.uvs is not None and not np.isfinite(chunk.uvs).all():
            bad = ~np.isfinite(chunk.uvs).all(axis=(1, 2))
            self.warn(f"{path}: {int(bad.sum())} triangles with NaN/Inf texture coordinates; their st set to 0")
            uvs = np.where(np.isfinite(chunk.uvs), chunk.uvs, 0.0).astype(chunk.uvs.dtype)
            chunk = _Chunk(chunk.points, chunk.tris, chunk.material, chunk.normals, uvs)
        if chunk.normals is not None:
            n = _normalized(chunk.normals)
            bad = ~np.isfinite(n).all(axis=(1, 2))
            if bad.any():  # zero or non-finite authored normals: faceted there
                n[bad] = _face_normals(chunk.points, chunk.tris[bad])[:, None, :]
            chunk = _Chunk(chunk.points, chunk.tris, chunk.material, n, chunk.uvs)
        if len(chunk.tris) == 0:
            return
        self.triangles += len(chunk.tris)
        if self.triangles > self.limits.triangles:
            hint = (f"; its subdivision surfaces are refined {self.subdivision_level} times, a lower "
                    f"subdivision level (0 renders their cages) makes fewer" if self.subdivided_meshes else "")
            raise SceneError(f"{path}: the scene has more than {self.limits.triangles} triangles (limit){hint}")
        sink.append(chunk)

    # -- skinning -------------------------------------------------------------------
    def skin(self) -> None:
        """Poses every skinned mesh at the render frame, as UsdSkel.BakeSkinning would: the
        skeleton's animation (SkelAnimation, else its rest pose) gives the skinning
        transforms, UsdSkel's skinning query applies them with each mesh's joint
        influences and geomBindTransform (linear blend or dual quaternion, as authored;
        rigid bindings as one transform). The posed points are in the skeleton's space."""
        from pxr import Usd, UsdSkel

        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        roots = [p for p in Usd.PrimRange.Stage(self.stage, predicate) if p.IsA(UsdSkel.Root)]
        if not roots:
            return
        cache = UsdSkel.Cache()
        for root_prim in roots:
            root = UsdSkel.Root(root_prim)
            cache.Populate(root, predicate)
            for binding in cache.ComputeSkelBindings(root, predicate):
                skel_query = cache.GetSkelQuery(binding.GetSkeleton())
                skel_world = self.world_matrix(skel_query.GetPrim())
                xforms = skel_query.ComputeSkinningTransforms(self.time)
                for query in binding.GetSkinningTargets():
                    prim = query.GetPrim()
                    path = str(prim.GetPath())
                    points = _skinnable_points(prim, self.time)
                    if points is None or xforms is None:
                        continue
                    if query.HasBlendShapes():
                        self._count_note("UsdSkel blend shapes are not applied (skinning is)")
                    if query.IsRigidlyDeformed():
                        m = np.array(query.ComputeSkinnedTransform(xforms, self.time), np.float64)
                        posed = np.asarray(points, np.float64) @ m[:3, :3] + m[3, :3]
                    else:
                        if not query.ComputeSkinnedPoints(xforms, points, self.time):
                            self.warn(f"{path}: UsdSkel could not skin this mesh; rendered in its rest pose")
                            continue
                        posed = np.asarray(points, np.float64)
                    self.skinned[path] = (posed, skel_world)
        if self.skinned:
            self._count_note(f"UsdSkel: {len(self.skinned)} skinned mesh(es) posed at the render frame")

    # -- meshes ---------------------------------------------------------------------
    def mesh_chunk(self, prim) -> _Chunk | None:
        from pxr import UsdGeom, UsdShade

        # Instance proxies of one prototype prim share its geometry: read it once; only
        # the material binding can differ per instance (skinned meshes are posed per prim).
        key = str(prim.GetPrimInPrototype().GetPath()) \
            if prim.IsInstanceProxy() and str(prim.GetPath()) not in self.skinned else None
        if key is not None and key in self._geometry_cache:
            geo = self._geometry_cache[key]
        else:
            geo = self._mesh_geometry(prim)
            if key is not None:
                self._geometry_cache[key] = geo
        if geo is None:
            return None
        points, tris, face_of_tri, normals, uv_set, n_faces = geo
        mesh = UsdGeom.Mesh(prim)
        t = self.time
        materials = np.zeros(len(tris), dtype=np.uint32)
        double_sided = bool(mesh.GetDoubleSidedAttr().Get(t))
        base_row = self.material_row(prim, prim, double_sided)
        materials[:] = base_row
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        if subsets:
            face_row = np.full(n_faces, base_row, dtype=np.uint32)
            for subset in subsets:
                idx = subset.GetIndicesAttr().Get(t)
                if idx is None or len(idx) == 0:
                    continue
                idx = np.asarray(idx, dtype=np.int64)
                idx = idx[(idx >= 0) & (idx < n_faces)]
                face_row[idx] = self.material_row(subset.GetPrim(), prim, double_sided)
            materials = face_row[face_of_tri]

        return _Chunk(points, tris, materials, normals, self._uvs_by_material(prim, materials, uv_set))

    def _uvs_by_material(self, prim, materials, uv_set):
        """Per-corner st of each triangle from the UV set its material's textures name
        (UsdPrimvarReader_float2 varname), so subsets bound to materials reading different
        sets each get theirs; the mesh's default set (DEFAULT_UV_SETS) where a material
        names none or names one the mesh lacks (with a warning)."""
        rows = np.unique(materials)
        wanted = {int(r): self._uv_set_of_row(int(r)) for r in rows}
        names = set(wanted.values())
        if names <= {None}:
            return uv_set(None)
        uvs = None
        for name in names:
            values = uv_set(name)
            if values is None and name is not None:
                fallback = uv_set(None)
                self._count_note(f"meshes lack the UV set {name!r} that their material's textures read "
                                 f"(UsdPrimvarReader_float2 varname); "
                                 + ("the mesh's default set is used" if fallback is not None
                                    else "those textures are sampled at st = (0, 0)"))
                values = fallback
            if values is None:
                continue
            if uvs is None:
                uvs = np.zeros((len(materials), 3, 2), np.float32)
            sel = np.isin(materials, [r for r, n in wanted.items() if n == name])
            uvs[sel] = values[sel]
        return uvs

    def _uv_set_of_row(self, row: int) -> str | None:
        """The UV set a material row's textures read (None: no reader, the default set).
        One set per material: textures reading several get the first, with a warning."""
        textures = self.materials.rows[row]["textures"]
        names = [self.materials.textures[t].get("st_primvar") for _, t in sorted(textures.items())]
        names = list(dict.fromkeys(n for n in names if n))
        if len(names) > 1:
            self._count_note(f"materials whose textures read several UV sets ({', '.join(names)}) are "
                             f"rendered with the first for all of them")
        return names[0] if names else None

    def _mesh_geometry(self, prim):
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh(prim)
        path = str(prim.GetPath())
        t = self.time
        points = mesh.GetPointsAttr().Get(t)
        skinned = self.skinned.get(path)
        if skinned is not None:
            points = skinned[0]
        counts = mesh.GetFaceVertexCountsAttr().Get(t)
        face_indices = mesh.GetFaceVertexIndicesAttr().Get(t)
        if points is None or counts is None or face_indices is None:
            self.warn(f"{path}: mesh has no points or faces; skipped")
            return None
        points, counts, face_indices = _float_rows(points, 3), _ints(counts), _ints(face_indices)
        if points is None or counts is None or face_indices is None:
            self.warn(f"{path}: points, faceVertexCounts or faceVertexIndices have the wrong type; skipped")
            return None
        if len(points) == 0 or len(counts) == 0:
            self.warn(f"{path}: mesh has no points or faces; skipped")
            return None
        if np.any(counts < 0):
            raise SceneError(f"{path}: faceVertexCounts has {int(np.count_nonzero(counts < 0))} negative "
                             f"entries (the first, {int(counts[counts < 0][0])}, at face {int(np.argmax(counts < 0))})")
        if counts.sum() != len(face_indices):
            raise SceneError(f"{path}: faceVertexCounts sum to {int(counts.sum())} but there are "
                             f"{len(face_indices)} faceVertexIndices")
        if len(face_indices) and (face_indices.min() < 0 or face_indices.max() >= len(points)):
            raise SceneError(f"{path}: faceVertexIndices reference vertex "
                             f"{int(face_indices.max() if face_indices.max() >= len(points) else face_indices.min())}"
                             f" but the mesh has {len(points)} points")
        if np.any(counts < 3):
            self.warn(f"{path}: {int(np.count_nonzero(counts < 3))} faces with fewer than 3 vertices skipped")

        corners, face_of_tri = _triangulate_corners(counts)
        _split_concave_quads(corners, counts, face_indices, points)
        holes = mesh.GetHoleIndicesAttr().Get(t)
        h = np.zeros(0, dtype=np.int64)
        if holes is not None and len(holes):
            hole = np.zeros(len(counts), bool)
            h = np.asarray(holes, dtype=np.int64)
            h = h[(h >= 0) & (h < len(counts))]
            hole[h] = True
            keep = ~hole[face_of_tri]
            corners, face_of_tri = corners[keep], face_of_tri[keep]
        tris = face_indices[corners]
        left = mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded
        if left:
            corners, tris = corners[:, ::-1], tris[:, ::-1]
        scheme = mesh.GetSubdivisionSchemeAttr().Get(t)
        if len(tris) == 0:
            return None
        api = UsdGeom.PrimvarsAPI(prim)
        shape = (len(points), len(counts), len(face_indices))
        if scheme not in (None, UsdGeom.Tokens.none):
            if self.subdivision_level == 0:
                self._count_note(f"subdivision surfaces ({scheme}) are rendered as their flat control "
                                 f"cage with smooth vertex normals (subdivision level 0)")
            else:
                refined = subdivision.refine(mesh, t, points, counts, face_indices, left,
                                             self._subdivision_level(counts, str(scheme), path), h,
                                             self._count_note)
                if refined is not None:
                    self.subdivided_meshes += 1
                    return self._refined_geometry(refined, api, shape, counts, face_indices, path)

        normals = None
        pv = api.GetPrimvar("normals")
        if pv and pv.HasAuthoredValue():
            normals = self.corner_primvar(pv, corners, tris, face_of_tri, shape, 3, path)
        if normals is None:
            raw = mesh.GetNormalsAttr().Get(t)
            raw = _float_rows32(raw, 3) if raw is not None else None
            if raw is None and mesh.GetNormalsAttr().HasAuthoredValue():
                self.warn(f"{path}: normals have the wrong type; ignored")
            if raw is not None and len(raw):
                interp = mesh.GetNormalsInterpolation()
                normals = _expand(raw, interp, None,
                                  corners, tris, face_of_tri, shape)
                if normals is None:
                    self.warn(f"{path}: normals have {len(raw)} values, wrong for {interp}; ignored")
        if normals is not None and skinned is not None:
            # Authored normals are the rest pose's: shade the posed surface smoothly.
            self._count_note("skinned meshes get smooth normals of the posed surface (their authored "
                             "normals are the rest pose's)")
            normals = _vertex_normals(points, tris)
        if normals is None and scheme not in (None, UsdGeom.Tokens.none):
            normals = _vertex_normals(points, tris)  # smooth look for the unsubdivided cage
        sets: dict = {}

        def uv_set(name: str | None):
            """Per-corner values of a named UV set, or of the default set for None;
            None when the mesh has no such primvar. Read once per name."""
            if name not in sets:
                if name is None:
                    found = [n for n in DEFAULT_UV_SETS if api.HasPrimvar(n)]
                    pv = api.GetPrimvar(found[0]) if found else None
                else:
                    pv = api.GetPrimvar(name) if api.HasPrimvar(name) else None
                sets[name] = self.corner_primvar(pv, corners, tris, face_of_tri, shape, 2, path) \
                    if pv is not None else None
            return sets[name]

        return points, tris, face_of_tri, normals, uv_set, len(counts)

    def _subdivision_level(self, counts, scheme: str, path: str) -> int:
        """The job's refinement level, lowered for a mesh whose refined triangles would pass
        its share of the triangle limit (with a note)."""
        n_quads = int(counts.sum()) if scheme != "loop" else 0  # an n-gon makes n quads
        n_tris = len(counts)
        budget = self.limits.triangles // subdivision.MESH_SHARE_OF_TRIANGLE_LIMIT
        level = self.subdivision_level
        while level > 1 and subdivision.refined_triangles(n_quads, n_tris, scheme, level) > budget:
            level -= 1
        if level < self.subdivision_level:
            self._count_note(f"subdivision meshes refined to level {level} instead of "
                             f"{self.subdivision_level} to stay within {budget} triangles each")
        return level

    def _refined_geometry(self, refined, api, shape, counts, face_indices, path):
        """_mesh_geometry's answer for a subdivided mesh: limit surface and limit normals
        (authored normals do not apply to subdivision surfaces, as the schema says); UV
        sets refined from their per-corner cage values."""
        n_corners = len(face_indices)
        cage_corners = np.arange(n_corners, dtype=np.int64)[:, None]
        corner_face = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
        cage_tris = face_indices[cage_corners]
        sets: dict = {}

        def uv_set(name: str | None):
            if name not in sets:
                if name is None:
                    found = [n for n in DEFAULT_UV_SETS if api.HasPrimvar(n)]
                    pv = api.GetPrimvar(found[0]) if found else None
                else:
                    pv = api.GetPrimvar(name) if api.HasPrimvar(name) else None
                values = self.corner_primvar(pv, cage_corners, cage_tris, corner_face, shape, 2, path) \
                    if pv is not None else None
                sets[name] = refined.face_varying(values[:, 0]) if values is not None else None
            return sets[name]

        return refined.points, refined.tris, refined.face_of_tri, refined.normals, uv_set, len(counts)

    def corner_primvar(self, pv, corners, tris, face_of_tri, shape, width, path):
        """A primvar of any interpolation, indexed or not, expanded to (T, 3, width)."""
        values = pv.Get(self.time)
        if values is None or len(values) == 0:
            return None
        values = _float_rows32(values, None)
        if values is None or values.shape[1] < width:
            self.warn(f"{path}: primvar {pv.GetPrimvarName()} has the wrong type; ignored")
            return None
        values = values[:, :width]
        indices = pv.GetIndices(self.time) if pv.IsIndexed() else None
        if indices is not None:
            indices = np.asarray(indices, dtype=np.int64)
            if len(indices) and (indices.min() < 0 or indices.max() >= len(values)):
                self.warn(f"{path}: {pv.GetPrimvarName()} indices out of range; primvar ignored")
                return None
        interp = pv.GetInterpolation()
        out = _expand(values, interp, indices, corners, tris, face_of_tri, shape)
        if out is None:
            self.warn(f"{path}: primvar {pv.GetPrimvarName()} has {len(values if indices is None else indices)} "
                      f"values, wrong for {interp} interpolation; ignored")
        return out

    def gprim_chunk(self, prim, type_name) -> _Chunk | None:
        from pxr import UsdGeom

        t = self.time
        g = getattr(UsdGeom, type_name)(prim)
        axis = g.GetAxisAttr().Get(t) if hasattr(g, "GetAxisAttr") else "Z"
        if type_name == "Sphere":
            pts, tris, nrm = gprims.sphere(float(g.GetRadiusAttr().Get(t)))
        elif type_name == "Cube":
            pts, tris, nrm = gprims.cube(float(g.GetSizeAttr().Get(t)))
        elif type_name == "Cylinder":
            pts, tris, nrm = gprims.cylinder(float(g.GetRadiusAttr().Get(t)), float(g.GetHeightAttr().Get(t)), axis)
        elif type_name == "Cone":
            pts, tris, nrm = gprims.cone(float(g.GetRadiusAttr().Get(t)), float(g.GetHeightAttr().Get(t)), axis)
        elif type_name == "Capsule":
            pts, tris, nrm = gprims.capsule(float(g.GetRadiusAttr().Get(t)), float(g.GetHeightAttr().Get(t)), axis)
        else:
            pts, tris, nrm = gprims.plane(float(g.GetWidthAttr().Get(t)), float(g.GetLengthAttr().Get(t)), axis)
        if not np.isfinite(pts).all():
            self.warn(f"{prim.GetPath()}: non-finite {type_name} size; skipped")
            return None
        double_sided = bool(g.GetDoubleSidedAttr().Get(t))
        row = self.material_row(prim, prim, double_sided)
        normals = nrm[tris] if type_name != "Cube" else None
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), normals, None)

    def curves_chunk(self, prim) -> _Chunk | None:
        geo = curves.curves_geometry(prim, self.time, self._count_note)
        if geo is None:
            return None
        pts, tris, normals, _ = geo
        row = self.material_row(prim, prim, False)
        return _Chunk(pts, tris, np.full(len(tris), row, np.uint32), normals, None)

    # -- instancing -----------------------------------------------------------------
    def prototype(self, key: str, prim_range, base_inv) -> int:
        """Index of a prototype, translating it once (geometry in its own space)."""
        if key in self._proto_index:
            return self._proto_index[key]
        chunks: list[_Chunk] = []
        self.walk(prim_range, base_inv, chunks, top_level=False)
        self._proto_index[key] = len(self.prototypes)
        self.prototypes.append({"chunks": chunks, "triangles": sum(len(c.tris) for c in chunks)})
        return self._proto_index[key]

    def native_key(self, prim) -> str:
        """Prototype key of a native instance: its USD prototype and the materials its
        gprims resolve to. Bindings authored on the instance or its ancestors (possibly
        strongerThanDescendants) reach the prototype's prims, so instances of one USD
        prototype bound differently become different prototypes here."""
        from pxr import Usd, UsdGeom, UsdShade

        def material(p) -> str:
            m = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()[0]
            if not m:
                return ""
            # A material inside the instance is an instance proxy: name it by its prototype
            # prim, which every instance shares (as material_row's cache does).
            mp = m.GetPrim()
            return str(mp.GetPrimInPrototype().GetPath() if mp.IsInstanceProxy() else mp.GetPath())

        sig = []
        for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
            if p.IsA(UsdGeom.Gprim):
                sig.append(material(p))
                for subset in UsdShade.MaterialBindingAPI(p).GetMaterialBindSubsets():
                    sig.append(material(subset.GetPrim()))
        return f"native:{prim.GetPrototype().GetPath()}:{'|'.join(sig)}"

    def add_native_instance(self, prim) -> None:
        from pxr import Usd

        # Walked through this instance's proxies (not the bare prototype prims), so that
        # material bindings from outside the prototype resolve as USD resolves them;
        # geometry is still read once per prototype prim (the geometry cache).
        rng = Usd.PrimRange(prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
        self._in_native_prototype = True
        try:
            idx = self.prototype(self.native_key(prim), rng, np.linalg.inv(self.world_matrix(prim)))
        finally:
            self._in_native_prototype = False
        self.instances.append(np.array([idx], np.uint32))
        self.instance_xforms.append(self.world_matrix(prim)[None])
        self.instanced_triangles += self.prototypes[idx]["triangles"]

    def add_point_instancer(self, prim, base_inv, sink, top_level) -> None:
        from pxr import Usd, UsdGeom

        pi = UsdGeom.PointInstancer(prim)
        path = str(prim.GetPath())
        targets = pi.GetPrototypesRel().GetForwardedTargets()
        proto_idx = pi.GetProtoIndicesAttr().Get(self.time)
        if proto_idx is None or len(proto_idx) == 0 or not targets:
            self.warn(f"{path}: PointInstancer has no instances or prototypes; skipped")
            return
        proto_idx = np.asarray(proto_idx, dtype=np.int64)
        if proto_idx.min() < 0 or proto_idx.max() >= len(targets):
            raise SceneError(f"{path}: protoIndices reference prototype {int(proto_idx.max())} "
                             f"but there are {len(targets)} prototypes")
        xforms = pi.ComputeInstanceTransformsAtTime(self.time, self.time, UsdGeom.PointInstancer.IncludeProtoXform,
                                                    UsdGeom.PointInstancer.IgnoreMask)
        if xforms is None or len(xforms) == 0:
            self.warn(f"{path}: positions/orientations/scales do not match protoIndices; skipped")
            return
        xforms = np.asarray(xforms, dtype=np.float64).reshape(-1, 4, 4)
        mask = np.asarray(pi.ComputeMaskAtTime(self.time) or [True] * len(proto_idx), bool)
        if len(xforms) != len(proto_idx):
            raise SceneError(f"{path}: {len(xforms)} instance transforms for {len(proto_idx)} protoIndices")
        world = self.world_matrix(prim)
        if base_inv is not None:
            world = world @ base_inv
        for k, target in enumerate(targets):
            sel = (proto_idx == k) & mask
            if not sel.any():
                continue
            proto_prim = self.stage.GetPrimAtPath(target)
            if not proto_prim:
                self.warn(f"{path}: prototype {target} does not exist; skipped")
                continue
            # ComputeInstanceTransformsAtTime includes the prototype root's own transform,
            # so prototype geometry is kept in the root's local frame.
            root_inv = np.linalg.inv(self.world_matrix(proto_prim))
            rng = Usd.PrimRange(proto_prim, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
            # A prototype that is itself a native instance shares that instance's prototype
            # (its own transform is in the instance transforms): translate it once.
            key = self.native_key(proto_prim) if proto_prim.IsInstance() else str(target)
            idx = self.prototype(key, rng, root_inv)
            mats = xforms[sel] @ world
            n = int(sel.sum())
            if self.instancing == "instances" and top_level:
                self.instances.append(np.full(n, idx, np.uint32))
                self.instance_xforms.append(mats)
                self.instanced_triangles += n * self.prototypes[idx]["triangles"]
            else:
                self.flatten_instances(idx, mats, sink, path)

    def flatten_instances(self, proto: int, mats: np.ndarray, sink: list, path: str) -> None:
        """Copies a prototype once per transform, vectorised over instances."""
        n = len(mats)
        total = n * self.prototypes[proto]["triangles"]
        self.instanced_triangles += total
        for c in self.prototypes[proto]["chunks"]:
            pts = np.einsum("vj,njk->nvk", c.points, mats[:, :3, :3]) + mats[:, None, 3, :3]
            flip = np.linalg.det(mats[:, :3, :3]) < 0
            v = len(c.points)
            tris = (c.tris[None] + (np.arange(n) * v)[:, None, None])
            tris = np.where(flip[:, None, None], tris[:, :, ::-1], tris).reshape(-1, 3)
            normals = None
            if c.normals is not None:
                inv_t = np.linalg.inv(mats[:, :3, :3]).transpose(0, 2, 1)
                normals = np.einsum("tcj,njk->ntck", c.normals, inv_t)
                normals = np.where(flip[:, None, None, None], normals[:, :, ::-1], normals).reshape(-1, 3, 3)
            uvs = None
            if c.uvs is not None:
                uvs = np.broadcast_to(c.uvs, (n,) + c.uvs.shape)
                uvs = np.where(flip[:, None, None, None], uvs[:, :, ::-1], uvs).reshape(-1, 3, 2)
            self.emit(_Chunk(pts.reshape(-1, 3), tris, np.tile(c.material, n), normals, uvs), sink, path)

    # -- materials ------------------------------------------------------------------
    def material_row(self, bind_prim, geom_prim, double_sided: bool) -> int:
        from pxr import UsdGeom, UsdShade

        material, _ = UsdShade.MaterialBindingAPI(bind_prim).ComputeBoundMaterial()
        display = None
        color = UsdGeom.Gprim(geom_prim).GetDisplayColorAttr().Get(self.time) if UsdGeom.Gprim(geom_prim) else None
        if color is not None and len(color) > 0:
            display = tuple(float(x) for x in color[0])
        if not material:
            surface = self._plain_surface(display, str(geom_prim.GetPath()))
        else:
            mprim = material.GetPrim()
            # Materials under instances are instance proxies: one read per prototype material.
            mpath = mprim.GetPrimInPrototype().GetPath() if mprim.IsInstanceProxy() else mprim.GetPath()
            key = (str(mpath), display)
            if key not in self._surface_cache:
                self._surface_cache[key] = self._read_preview_surface(material, display)
            surface = self._surface_cache[key]
        return self.materials.add(surface, double_sided)

    def _plain_surface(self, display, path) -> dict:
        values = {k: v for k, v in self.defaults.items()}
        if display is not None:
            values["diffuseColor"] = display
        values["diffuseColor"] = self._clamped_albedo(values["diffuseColor"], path)
        return {"values": values, "textures": {}}

    def _read_preview_surface(self, material, display) -> dict:
        from . import mtlx

        path = str(material.GetPath())
        # The universal surface first (what Storm, the reference viewer, shows too), then
        # a MaterialX one (outputs:mtlx:surface), then a referenced .mtlx document.
        shader, _, _ = material.ComputeSurfaceSource()
        if not shader:
            shader, _, _ = material.ComputeSurfaceSource("mtlx")
        ident = shader.GetIdAttr().Get() if shader else None
        if ident != "UsdPreviewSurface":
            if mtlx.category_of(ident) in mtlx.SURFACE_CATEGORIES:
                return self._mtlx_surface(mtlx.UsdNode(shader, self.time), path)
            reason = ident or "no surface shader"
            if not shader:
                node, why = self._referenced_mtlx(material)
                if node is not None and node.category in mtlx.SURFACE_CATEGORIES:
                    return self._mtlx_surface(node, path)
                reason = why or (f"MaterialX {node.category}" if node is not None else reason)
            self.grey_materials[path] = reason
            return self._plain_surface(None, path)
        values, textures = {}, {}
        for name in _COLOR_INPUTS + tuple(_SCALAR_INPUTS) + ("normal", "occlusion"):
            default = self.defaults.get(name) or {"normal": (0.0, 0.0, 1.0), "occlusion": (1.0,)}[name]
            value, tex = self._input(shader, name, default, path, display)
            if name in self.defaults:
                values[name] = value
            if tex is not None:
                textures[name] = self.materials.add_texture(tex)
                if name == "normal" and tex["scale"][:3] == [1.0, 1.0, 1.0] and tex["bias"][:3] == [0.0, 0.0, 0.0]:
                    # Read as authored (the spec's rule), which tilts every normal: say so.
                    # One line for the scene however many maps: Storm (the spec's reference
                    # viewer) does not remap either, so the image matches usdview's.
                    self._count_note("normal maps without scale (2, 2, 2) and bias (-1, -1, -1) are read as "
                                     "authored, as the UsdPreviewSurface spec and usdview do (values in [0, 1] "
                                     "tilt every normal); set them in the file to decode 8-bit maps")
        values["diffuseColor"] = self._clamped_albedo(values["diffuseColor"], path)
        values["emissiveColor"] = _non_negative(values["emissiveColor"])
        if self._is_presence(shader, values, "opacity" in textures):
            values["opacityThreshold"] = (PRESENCE_MODE,)
        return {"values": values, "textures": textures, "preview": True}

    def _is_presence(self, shader, values, textured_opacity: bool) -> bool:
        """Whether the surface's opacity means presence (partial coverage, no refraction)
        rather than glass. UsdPreviewSurface's reference viewer (Storm) blends a partial
        opacity as translucency and refracts nothing; a path tracer refracting every
        partially opaque surface turns exporters' window panes (Mineways' glass at 0.57)
        into dark glass with fireflies. So: a cutout (opacityThreshold > 0) stays one;
        opacityMode "presence" is presence; otherwise a partial or textured opacity is
        presence unless the author asks for refraction by authoring `ior`; opacity 0
        (clear glass, whose specular response the spec keeps) stays glass."""
        threshold, opacity = values["opacityThreshold"][0], values["opacity"][0]
        if threshold > 0:
            return False
        partial = textured_opacity or 0.0 < opacity < 1.0
        if str(_input_value(shader, "opacityMode", self.time) or "transparent") == "presence":
            return partial or opacity < 1.0
        if not partial:
            return False
        ior = shader.GetInput("ior")
        if ior and (ior.GetAttr().HasAuthoredValue() or ior.HasConnectedSource()):
            return False
        self._count_note("partial opacity without an authored ior renders as presence (translucent "
                         "without refraction, as usdview shows it); author ior to make it refract")
        return True

    def _mtlx_surface(self, node, path) -> dict:
        """A MaterialX surface (inline or from a .mtlx file) as UsdPreviewSurface values."""
        from . import mtlx

        values, textures, presence = mtlx.surface(node, self.defaults, self._texture_from, self._count_note)
        values = {k: v for k, v in values.items() if k in self.defaults}
        values["diffuseColor"] = self._clamped_albedo(values["diffuseColor"], path)
        values["emissiveColor"] = _non_negative(values["emissiveColor"])
        if presence is None:  # MaterialX's UsdPreviewSurface node: the UsdPreviewSurface rule
            partial = "opacity" in textures or 0.0 < values["opacity"][0] < 1.0
            presence = values["opacityThreshold"][0] <= 0 and partial and node.value("ior") is None
        if presence:
            values["opacityThreshold"] = (PRESENCE_MODE,)
        return {"values": values, "textures": {k: self.materials.add_texture(t) for k, t in textures.items()},
                "preview": True}

    def _referenced_mtlx(self, material):
        """(MxNode of the surface, None) for a Material prim that references or payloads a
        .mtlx document (the usdMtlx convention), (None, reason) when that fails, (None,
        None) when it names none."""
        import os

        from . import mtlx

        prim = material.GetPrim()
        for spec in prim.GetPrimStack():
            arcs = list(spec.referenceList.GetAddedOrExplicitItems()) + \
                list(spec.payloadList.GetAddedOrExplicitItems())
            for arc in arcs:
                if not arc.assetPath.lower().endswith(".mtlx"):
                    continue
                anchor = os.path.dirname(spec.layer.realPath)
                where = f"{prim.GetPath()}: {arc.assetPath}"
                if self.bundle is not None:
                    file = self.bundle.check_asset(arc.assetPath, anchor, what=where)
                else:
                    file = os.path.join(anchor, arc.assetPath)
                if not os.path.isfile(file):
                    return None, f"{arc.assetPath} missing"
                name = arc.primPath.name if not arc.primPath.isEmpty else prim.GetName()
                return mtlx.read_mtlx_material(str(file), name, where)
        return None, None

    def _input(self, shader, name, default, path, display):
        """(value, texture description or None) of a UsdPreviewSurface input."""
        from pxr import UsdShade

        inp = shader.GetInput(name)
        if not inp:
            return default, None
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Output.IsOutput(attr) or attr.GetName().startswith("outputs:"):
                src = UsdShade.Shader(attr.GetPrim())
                ident = src.GetIdAttr().Get() if src else None
                out_name = attr.GetName().split(":", 1)[1]
                if ident == "UsdUVTexture":
                    return self._texture(src, out_name, name, default, path)
                if ident and ident.startswith("UsdPrimvarReader"):
                    return self._primvar_reader_value(src, name, default, display), None
                self._count_note(f"shader networks other than UsdUVTexture/UsdPrimvarReader are not "
                                 f"evaluated; their inputs use the fallback ({ident})")
                return default, None
            value = attr.Get(self.time)
            if value is not None:
                return _as_tuple(value), None
        return default, None

    def _primvar_reader_value(self, reader, name, default, display):
        var = _input_value(reader, "varname", self.time)
        if var in ("displayColor", "primvars:displayColor") and display is not None:
            return display if len(default) == 3 else (sum(display) / 3,)
        fb = _input_value(reader, "fallback", self.time)
        if fb is not None:
            fb = _as_tuple(fb)
            return fb[:len(default)] if len(fb) >= len(default) else (fb[0],) * len(default)
        return default

    def _texture(self, tex_shader, channel, input_name, default, path):
        from pxr import Sdf

        t = self.time
        fallback = _input_value(tex_shader, "fallback", t)
        fallback = tuple(float(x) for x in (fallback if fallback is not None else self.tex_defaults["fallback"]))
        value = _channel_value(fallback, channel, len(default))
        file_attr = tex_shader.GetInput("file")
        asset = None
        if file_attr:
            for a in file_attr.GetValueProducingAttributes():
                asset = a.Get(t)
                layer_dir = None
                spec_layer = _authoring_layer(a)
                if spec_layer is not None:
                    import os
                    layer_dir = os.path.dirname(spec_layer.realPath)
                break
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            self._count_note("UsdUVTexture without a file uses its fallback")
            return value, None
        where = f"{tex_shader.GetPath()}"
        tex = self._texture_from(
            asset=asset, anchor=layer_dir, where=where, input_name=input_name, channel=channel,
            fallback=list(_vec4(fallback, self.tex_defaults["fallback"])),
            wrap_s=_wrap(_input_value(tex_shader, "wrapS", t)), wrap_t=_wrap(_input_value(tex_shader, "wrapT", t)),
            scale=list(_vec4(_input_value(tex_shader, "scale", t), self.tex_defaults["scale"])),
            bias=list(_vec4(_input_value(tex_shader, "bias", t), self.tex_defaults["bias"])),
            color_space=str(_input_value(tex_shader, "sourceColorSpace", t) or "auto"), st_primvar=None,
            transform2d=None)
        if tex is None:
            return value, None
        tex.update(self._st_source(tex_shader))
        return value, tex

    def _texture_from(self, *, asset, anchor, where, input_name, channel, fallback, wrap_s, wrap_t, scale,
                      bias, color_space, st_primvar, transform2d) -> dict | None:
        """A texture description for an image file named in the scene (an Sdf.AssetPath,
        or a path relative to `anchor` from a .mtlx document), checked by the sandbox and
        the pixel limit; None (with a warning) when it is missing or unreadable."""
        from pxr import Sdf

        authored = asset.path if isinstance(asset, Sdf.AssetPath) else str(asset or "")
        if not authored:
            self._count_note("textures without a file use their fallback")
            return None
        if self.bundle is None:
            file_path = None
        elif isinstance(asset, Sdf.AssetPath):
            file_path = self.bundle.resolve_texture(asset, anchor, where)
        else:
            file_path = self.bundle.check_asset(authored, anchor, what=f"texture of {where}")
            file_path = file_path if file_path.is_file() else None
        if file_path is None:
            self.warn(f"{where}: texture {authored!r} is missing from the bundle; using its fallback")
            return None
        info = _texture_info(file_path)
        if info is None:
            self.warn(f"{where}: texture {authored!r} cannot be read; using its fallback")
            return None
        w, h, bits, channels = info
        if w * h > self.limits.texture_pixels:
            raise SceneError(f"{where}: texture {authored!r} is {w}x{h}, more than the limit of "
                             f"{self.limits.texture_pixels} pixels")
        if color_space == "auto":
            # 8-bit colour images (3 or 4 channels) feeding a colour input are sRGB-encoded
            # by convention; deeper images, grey images and data (roughness, normals, ...)
            # are linear.
            color_space = "sRGB" if bits <= 8 and channels >= 3 and input_name in _COLOR_INPUTS else "raw"
        return {"file": str(file_path), "wrap_s": wrap_s, "wrap_t": wrap_t, "scale": list(scale),
                "bias": list(bias), "fallback": list(fallback),
                "color_space": "sRGB" if color_space.lower() == "srgb" else "raw",
                "channel": channel, "width": w, "height": h, "udim": "<UDIM>" in authored,
                "st_primvar": st_primvar, "transform2d": transform2d}

    def _st_source(self, tex_shader) -> dict:
        """Which primvar feeds the texture's st, and any UsdTransform2d on the way."""
        from pxr import UsdShade

        out = {"st_primvar": None, "transform2d": None}
        inp = tex_shader.GetInput("st")
        if not inp:
            return out
        for attr in inp.GetValueProducingAttributes():
            if not attr.GetName().startswith("outputs:"):
                return out
            node = UsdShade.Shader(attr.GetPrim())
            ident = node.GetIdAttr().Get() if node else None
            if ident == "UsdTransform2d":
                out["transform2d"] = {
                    "scale": list(_as_tuple(_input_value(node, "scale", self.time) or (1.0, 1.0))),
                    "rotation": float(_input_value(node, "rotation", self.time) or 0.0),
                    "translation": list(_as_tuple(_input_value(node, "translation", self.time) or (0.0, 0.0)))}
                inner = node.GetInput("in")
                node = None
                if inner:
                    for a2 in inner.GetValueProducingAttributes():
                        if a2.GetName().startswith("outputs:"):
                            node = UsdShade.Shader(a2.GetPrim())
            if node and (node.GetIdAttr().Get() or "").startswith("UsdPrimvarReader"):
                # varname may come through a connection to a material interface input
                # (e.g. inputs:frame:stPrimvarName): GetValueProducingAttributes follows it.
                var = _input_value(node, "varname", self.time)
                if var:
                    var = str(var)
                    out["st_primvar"] = var[len("primvars:"):] if var.startswith("primvars:") else var
        return out

    def _clamped_albedo(self, color, path) -> tuple:
        c = tuple(float(x) for x in color)
        if not all(math.isfinite(x) for x in c):
            self.warn(f"{path}: non-finite diffuse colour replaced by the default")
            return self.default_diffuse
        clamped = tuple(min(max(x, 0.0), 1.0) for x in c)
        if clamped != c:
            self.warn(f"{path}: diffuse colour {c} clamped to [0, 1] (energy conservation)")
        return clamped

    # -- lights ---------------------------------------------------------------------
    def light_radiance(self, prim, area: float | None) -> np.ndarray:
        from pxr import UsdLux

        light = UsdLux.LightAPI(prim)
        t = self.time
        color = np.array(light.GetColorAttr().Get(t) or (1.0, 1.0, 1.0), dtype=np.float64)
        intensity = light.GetIntensityAttr().Get(t)
        exposure = light.GetExposureAttr().Get(t)
        radiance = color * (1.0 if intensity is None else intensity) * 2.0 ** (exposure or 0.0)
        if light.GetEnableColorTemperatureAttr().Get(t):
            kelvin = light.GetColorTemperatureAttr().Get(t) or 6500.0
            radiance = radiance * gprims.blackbody_rgb(kelvin)
        if area is not None and light.GetNormalizeAttr().Get(t):
            radiance = radiance / area
        if not np.isfinite(radiance).all() or (radiance < 0).any():
            raise SceneError(f"{prim.GetPath()}: light radiance {radiance.tolist()} must be finite and >= 0")
        if prim.HasAPI(UsdLux.ShapingAPI) and prim.GetTypeName() not in ("SphereLight",):
            self._count_note("UsdLux ShapingAPI (cone, focus, IES) on Rect, Disk, Cylinder and Distant "
                             "lights is ignored: they emit unshaped")
        return radiance

    def add_light(self, prim, type_name: str) -> None:
        handler = {"RectLight": self.add_rect_light, "SphereLight": self.add_sphere_light,
                   "DiskLight": self.add_disk_light, "CylinderLight": self.add_cylinder_light,
                   "DistantLight": self.add_distant_light, "DomeLight": self.add_dome_light}.get(type_name)
        if handler is None:
            self.unsupported[type_name or "untyped light"] += 1
            return
        handler(prim)

    def _emissive(self, prim, local_pts, tris, radiance, two_sided=False) -> None:
        m = self.world_matrix(prim)
        surface = {"values": {**self.defaults, "diffuseColor": (0.0, 0.0, 0.0),
                              "emissiveColor": tuple(float(x) for x in radiance)}, "textures": {}}
        row = self.materials.add(surface, two_sided)
        chunk = _Chunk(np.asarray(local_pts, np.float64), np.asarray(tris), np.full(len(tris), row, np.uint32))
        self.emit(chunk.transformed(m), self.chunks, str(prim.GetPath()))

    def add_rect_light(self, prim) -> None:
        from pxr import UsdLux

        rect = UsdLux.RectLight(prim)
        w = float(rect.GetWidthAttr().Get(self.time) or 0.0)
        h = float(rect.GetHeightAttr().Get(self.time) or 0.0)
        if rect.GetTextureFileAttr().Get(self.time):
            self.warn(f"{prim.GetPath()}: RectLight texture is not supported yet; using its colour")
        # Wound so the geometric normal is local -Z, the emitting side.
        local = np.array([[-w / 2, -h / 2, 0], [-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0]])
        m = self.world_matrix(prim)
        world = local @ m[:3, :3] + m[3, :3]
        area = float(np.linalg.norm(np.cross(world[1] - world[0], world[3] - world[0])))
        if not (area > 0.0) or not np.isfinite(world).all():
            self.warn(f"{prim.GetPath()}: RectLight has no area; skipped")
            return
        self._emissive(prim, local, [[0, 1, 2], [0, 2, 3]], self.light_radiance(prim, area))

    def add_disk_light(self, prim) -> None:
        from pxr import UsdLux

        r = float(UsdLux.DiskLight(prim).GetRadiusAttr().Get(self.time) or 0.0)
        m = self.world_matrix(prim)
        # True disk area (not the polygon's): a non-uniform scale stretches it to an ellipse.
        area = math.pi * r * r * float(np.linalg.norm(np.cross(m[0, :3], m[1, :3])))
        if not (area > 0.0) or not math.isfinite(area):
            self.warn(f"{prim.GetPath()}: DiskLight has no area; skipped")
            return
        pts, tris = gprims.disk_light(r)
        self._emissive(prim, pts, tris, self.light_radiance(prim, area))

    def add_cylinder_light(self, prim) -> None:
        from pxr import UsdLux

        cyl = UsdLux.CylinderLight(prim)
        r = float(cyl.GetRadiusAttr().Get(self.time) or 0.0)
        length = float(cyl.GetLengthAttr().Get(self.time) or 0.0)
        if cyl.GetTreatAsLineAttr().Get(self.time):
            self.warn(f"{prim.GetPath()}: CylinderLight treatAsLine is ignored; rendered as a cylinder")
        m = self.world_matrix(prim)
        sx = float(np.linalg.norm(m[0, :3]))
        s_round = float(np.sqrt(np.linalg.norm(m[1, :3]) * np.linalg.norm(m[2, :3])))
        # Side area only: the caps do not emit (UsdLux).
        area = 2.0 * math.pi * r * s_round * length * sx
        if not (area > 0.0) or not math.isfinite(area):
            self.warn(f"{prim.GetPath()}: CylinderLight has no area; skipped")
            return
        pts, tris = gprims.cylinder_light(r, length)
        self._emissive(prim, pts, tris, self.light_radiance(prim, area))

    def add_sphere_light(self, prim) -> None:
        from pxr import UsdLux

        sphere = UsdLux.SphereLight(prim)
        radius = float(sphere.GetRadiusAttr().Get(self.time) or 0.0)
        m = self.world_matrix(prim)
        scales = np.linalg.norm(m[:3, :3], axis=1)
        if not np.allclose(scales, scales[0], rtol=1e-4):
            self.warn(f"{prim.GetPath()}: non-uniform scale on a SphereLight; using the mean scale")
        radius *= float(scales.mean())
        center = m[3, :3]
        shaping = light_shaping.shaping_columns(self, prim)
        if shaping is not None and not sphere.GetTreatAsPointAttr().Get(self.time) and radius > 0:
            # A spot light as Omniverse writes it: a shaped sphere. Shaped as a point at its
            # centre emitting what the sphere would (the sphere's size only softens shadows).
            self._count_note("shaped SphereLights (spot lights) are rendered as shaped point lights at "
                             "their centre (hard shadows)")
            radiance = self.light_radiance(prim, 4.0 * math.pi * radius * radius)
            self.point_lights.append([*center, *(radiance * math.pi * radius * radius), *shaping])
            return
        if sphere.GetTreatAsPointAttr().Get(self.time):
            # The point emits what the sphere would, seen from afar: intensity = L * pi r^2
            # (W/sr); a sphere of radius 0 then has none unless it is normalized... in which
            # case L * pi r^2 = I / 4 for any r.
            rr = radius if radius > 0 else 0.0
            if rr > 0:
                radiance = self.light_radiance(prim, 4.0 * math.pi * rr * rr)
                intensity = radiance * math.pi * rr * rr
            else:
                norm = UsdLux.LightAPI(prim).GetNormalizeAttr().Get(self.time)
                intensity = self.light_radiance(prim, None) * (0.25 if norm else 0.0)
            self.point_lights.append([*center, *intensity, *(shaping or [])])
            return
        if not (radius > 0.0) or not math.isfinite(radius):
            self.warn(f"{prim.GetPath()}: SphereLight has no radius; skipped")
            return
        radiance = self.light_radiance(prim, 4.0 * math.pi * radius * radius)
        self.sphere_lights.append([*center, radius, *radiance])

    def add_distant_light(self, prim) -> None:
        from pxr import UsdLux

        m = self.world_matrix(prim)
        direction = -m[2, :3]
        direction = direction / np.linalg.norm(direction)
        angle = float(UsdLux.DistantLight(prim).GetAngleAttr().Get(self.time) or 0.0)
        half = math.radians(min(max(angle, 0.0), 180.0)) / 2.0
        # normalize: intensity is the illuminance on a surface facing the light, so
        # radiance = E / (pi sin^2 half). For a delta light (angle 0) the row holds that
        # illuminance directly (documented in docs/scene-translation.md).
        radiance = self.light_radiance(prim, None)
        if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(self.time) and half > 0:
            radiance = radiance / (math.pi * math.sin(half) ** 2)
        self.distant_lights.append([*direction, half, *radiance])

    def add_dome_light(self, prim) -> None:
        from pxr import UsdGeom, UsdLux

        if self.dome_light is not None:
            self.warn(f"{prim.GetPath()}: more than one DomeLight; only the first is used")
            return
        dome = UsdLux.DomeLight(prim)
        radiance = self.light_radiance(prim, None)
        texture = None
        asset = dome.GetTextureFileAttr().Get(self.time)
        if asset is not None and asset.path:
            attr = dome.GetTextureFileAttr()
            layer = _authoring_layer(attr)
            import os
            path = self.bundle.resolve_texture(asset, os.path.dirname(layer.realPath) if layer else None,
                                               str(prim.GetPath())) if self.bundle else None
            if path is None:
                self.warn(f"{prim.GetPath()}: dome texture {asset.path!r} is missing; using its colour")
            else:
                texture = str(path)
        pole = dome.GetPoleAxisAttr().Get(self.time) if hasattr(dome, "GetPoleAxisAttr") else "scene"
        up = UsdGeom.GetStageUpAxis(self.stage)
        m = self.world_matrix(prim)[:3, :3]
        # Column-vector light-to-world; the lat-long map's pole is light-space +Y.
        l2w = m.T / np.linalg.norm(m.T, axis=0, keepdims=True)
        if pole == "Z" or (pole in (None, "scene") and up == "Z"):
            rx = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # +Y -> +Z
            l2w = l2w @ rx
        self.dome_light = {"radiance": [float(x) for x in radiance], "texture": texture,
                           "world_to_light": np.linalg.inv(l2w).tolist(), "path": str(prim.GetPath())}

    # -- bookkeeping ----------------------------------------------------------------
    def _count_note(self, message: str) -> None:
        self._notes[message] += 1

    def flush_notes(self) -> None:
        if self.grey_materials:
            items = [f"{p} ({why})" for p, why in sorted(self.grey_materials.items())]
            self.warn(f"{len(items)} material(s) fell back to the default grey: " + ", ".join(items[:20])
                      + (f" and {len(items) - 20} more" if len(items) > 20 else ""))
        for message, count in self._notes.items():
            self.warn(message + (f" ({count} times)" if count > 1 else ""))


def _skinnable_points(prim, time):
    """A mesh's points at `time` as a mutable Vt array (the skinning query writes into it)."""
    from pxr import UsdGeom, Vt

    value = UsdGeom.PointBased(prim).GetPointsAttr().Get(time) if UsdGeom.PointBased(prim) else None
    return Vt.Vec3fArray(value) if value is not None else None


def _authoring_layer(attr):
    """The layer whose opinion gives an attribute its value (for anchoring asset paths)."""
    for spec in attr.GetPropertyStack():
        if spec.HasDefaultValue() or spec.layer.GetNumTimeSamplesForPath(spec.path):
            return spec.layer
    return None


def _input_value(shader, name, time):
    inp = shader.GetInput(name)
    if not inp:
        return None
    for attr in inp.GetValueProducingAttributes():
        if attr.GetName().startswith("outputs:"):
            return None
        return attr.Get(time)
    return None


def _normalized(v: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return v / np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]


def _float_rows(value, width: int | None, dtype=np.float64) -> np.ndarray | None:
    """A USD array value as float64 (N, width), or None when it is not an array of
    width-vectors (files do author scalars or ints where arrays of vectors belong)."""
    try:
        a = np.asarray(value)
    except Exception:
        return None
    if a.ndim == 1 and width is None and a.dtype.kind == "f":
        a = a[:, None]
    if a.ndim != 2 or a.dtype.kind != "f" or (width is not None and a.shape[1] != width):
        return None
    return a.astype(dtype, copy=False)


def _float_rows32(value, width: int | None) -> np.ndarray | None:
    return _float_rows(value, width, np.float32)


def _ints(value) -> np.ndarray | None:
    try:
        a = np.asarray(value)
    except Exception:
        return None
    if a.ndim != 1 or a.dtype.kind not in "iu":
        return None
    return a.astype(np.int64, copy=False)


def _as_tuple(value) -> tuple:
    if isinstance(value, (int, float, bool)):
        return (float(value),)
    try:
        return tuple(float(x) for x in value)
    except TypeError:
        return (float(value),)


def _vec4(value, default) -> tuple:
    v = _as_tuple(value if value is not None else default)
    return tuple(v[:4]) + (0.0,) * (4 - len(v))


def _channel_value(fallback4: tuple, channel: str, width: int) -> tuple:
    f = tuple(fallback4) + (0.0,) * (4 - len(fallback4))
    pick = {"r": (f[0],), "g": (f[1],), "b": (f[2],), "a": (f[3],), "rgb": f[:3]}.get(channel, f[:3])
    if len(pick) == width:
        return pick
    return (pick[0],) * width if width != 1 else (pick[0],)


def _wrap(value) -> str:
    v = str(value or "useMetadata")
    return v if v in ("black", "clamp", "repeat", "mirror") else "useMetadata"


def _texture_info(path) -> tuple[int, int, int, int] | None:
    """(width, height, bits per channel, channels) from the image header, without decoding pixels.
    UDIM sets report their largest tile."""
    import glob

    import OpenImageIO as oiio

    files = [str(path)]
    if "<UDIM>" in str(path):
        files = glob.glob(str(path).replace("<UDIM>", "1[0-9][0-9][0-9]"))
    best = None
    for f in files:
        inp = oiio.ImageInput.open(f)
        if not inp:
            oiio.geterror()
            return None
        spec = inp.spec()
        inp.close()
        bits = {oiio.UINT8: 8, oiio.INT8: 8}.get(spec.format.basetype, 16)
        if best is None or spec.width * spec.height > best[0] * best[1]:
            best = (spec.width, spec.height, bits, spec.nchannels)
    return best


def _non_negative(color) -> tuple:
    c = tuple(float(x) for x in color)
    if not all(math.isfinite(x) for x in c):
        return (0.0, 0.0, 0.0)
    return tuple(max(x, 0.0) for x in c)


def _triangulate_corners(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation in face-vertex space: face with n vertices -> n-2 triangles
    (c0, ck, ck+1) as indices into faceVertexIndices, and the face of each triangle.
    Faces with fewer than 3 vertices yield nothing. Vectorised over all faces."""
    starts = np.cumsum(counts) - counts
    n_tris = np.maximum(counts - 2, 0)
    total = int(n_tris.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    face = np.repeat(np.arange(len(counts)), n_tris)
    face_start = starts[face]
    first_tri = np.cumsum(n_tris) - n_tris
    k = np.arange(total) - first_tri[face] + 1
    return np.stack([face_start, face_start + k, face_start + k + 1], axis=1), face


def _split_concave_quads(corners, counts, face_indices, points) -> None:
    """A concave quad whose reflex vertex is corner 1 or 3 puts the fan's diagonal 0-2
    outside it: split those along 1-3 instead (in place, vectorised over all quads)."""
    n_tris = np.maximum(counts - 2, 0)
    quads = np.nonzero(counts == 4)[0]
    if len(quads) == 0:
        return
    first = (np.cumsum(n_tris) - n_tris)[quads]
    pts32 = points.astype(np.float32)
    for at in range(0, len(first), 1 << 18):  # in slices: bounded temporaries
        t0 = first[at:at + (1 << 18)]
        c0, c1, c2 = corners[t0].T
        c3 = corners[t0 + 1, 2]
        p = pts32[face_indices[np.stack([c0, c1, c2, c3], axis=1)]]
        normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])  # the quad's Newell normal (x2)
        bad = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), normal) < 0
        bad |= np.einsum("ij,ij->i", np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]), normal) < 0
        if bad.any():
            corners[t0[bad]] = np.stack([c1, c2, c3], axis=1)[bad]
            corners[t0[bad] + 1] = np.stack([c1, c3, c0], axis=1)[bad]


def _triangulate_fan(counts: np.ndarray, face_indices: np.ndarray) -> np.ndarray:
    """Fan-triangulates polygons into vertex-index triangles (see _triangulate_corners)."""
    corners, _ = _triangulate_corners(np.asarray(counts, np.int64))
    return np.asarray(face_indices)[corners]


def _expand(values, interp, indices, corners, tris, face_of_tri, shape):
    """Per-corner values (T, 3, k) from a primvar of any interpolation; None if the
    number of values does not fit the interpolation."""
    n_points, n_faces, n_fv = shape
    if indices is not None:
        n_values = len(indices)
    else:
        n_values = len(values)

    def take(i):
        return values[indices[i]] if indices is not None else values[i]

    if interp == "constant":
        if n_values < 1:
            return None
        return np.broadcast_to(take(np.array([0]))[0], (len(tris), 3, values.shape[1])).copy()
    if interp == "uniform":
        if n_values != n_faces:
            return None
        return np.repeat(take(face_of_tri)[:, None, :], 3, axis=1)
    if interp in ("vertex", "varying"):
        if n_values != n_points:
            return None
        return take(tris)
    if interp == "faceVarying":
        if n_values != n_fv:
            return None
        return take(corners)
    return None


def _face_normals(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    p = points[tris]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    with np.errstate(all="ignore"):
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
    return np.nan_to_num(n, nan=0.0)


def _vertex_normals(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted smooth vertex normals, as per-corner (T, 3, 3)."""
    p = points[tris]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    acc = np.zeros_like(points)
    for c in range(3):
        np.add.at(acc, tris[:, c], fn)
    with np.errstate(all="ignore"):
        acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    return np.nan_to_num(acc, nan=0.0)[tris]


def _find_render_settings(stage, warn):
    from pxr import UsdRender

    settings = UsdRender.Settings.GetStageRenderSettings(stage)
    if settings:
        return settings
    candidates = [p for p in stage.Traverse() if p.IsA(UsdRender.Settings)]
    if len(candidates) == 1:
        return UsdRender.Settings(candidates[0])
    if len(candidates) > 1:
        warn(f"{len(candidates)} RenderSettings prims and no renderSettingsPrimPath; using none of them")
    return None


def _camera_from_prim(prim, xform_cache, time, warn) -> CameraDesc:
    from pxr import UsdGeom

    cam = UsdGeom.Camera(prim)
    def authored(attr, fallback):  # an authored 0 is an error below, not the fallback
        value = attr.Get(time)
        return float(fallback if value is None else value)
    focal = authored(cam.GetFocalLengthAttr(), 50.0)
    hap = authored(cam.GetHorizontalApertureAttr(), 20.955)
    vap = authored(cam.GetVerticalApertureAttr(), 15.2908)
    path = str(prim.GetPath())
    if not all(math.isfinite(v) and v > 0 for v in (focal, hap, vap)):
        raise SceneError(f"{path}: focalLength and apertures must be positive "
                         f"(got {focal}, {hap}, {vap})")
    # The core takes tan(half angle) = aperture / (2 focalLength) as a float32: it must be
    # neither 0 nor infinite there (e.g. focalLength 1e-45 passes the check above).
    if not all(1e-30 < ap / (2.0 * focal) < 1e30 for ap in (hap, vap)):
        raise SceneError(f"{path}: the field of view is degenerate (apertures {hap}, {vap} over "
                         f"focalLength {focal})")
    if cam.GetProjectionAttr().Get(time) == UsdGeom.Tokens.orthographic:
        warn(f"{path}: orthographic projection is not supported yet; rendered as perspective")
    if (cam.GetHorizontalApertureOffsetAttr().Get(time) or 0.0) or (cam.GetVerticalApertureOffsetAttr().Get(time) or 0.0):
        warn(f"{path}: aperture offsets are ignored")
    m = np.array(xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64)
    origin = m[3, :3]
    forward = _unit(-m[2, :3])
    right = _unit(m[0, :3] - np.dot(m[0, :3], forward) * forward)
    up = np.cross(right, forward)
    if not np.isfinite(np.concatenate([origin, forward, right, up])).all():
        raise SceneError(f"{path}: camera transform is degenerate")
    # Depth of field: focalLength is in tenths of a scene unit, fStop 0 means a pinhole.
    f_stop = float(cam.GetFStopAttr().Get(time) or 0.0)
    focus = float(cam.GetFocusDistanceAttr().Get(time) or 0.0)
    lens_radius = 0.0
    if f_stop > 0.0 and math.isfinite(f_stop):
        if focus > 0.0 and math.isfinite(focus):
            lens_radius = 0.1 * focal / (2.0 * f_stop)
        else:
            warn(f"{path}: fStop {f_stop:g} without a positive focusDistance; rendered without depth of field")
    # Only an authored clipping range clips: the schema's fallback (1, 1e6) would cut away
    # whatever lies within one unit of the camera in scenes that never asked for it.
    clip_attr = cam.GetClippingRangeAttr()
    clip = clip_attr.Get(time) if clip_attr.HasAuthoredValue() else None
    near, far = (float(clip[0]), float(clip[1])) if clip is not None else (0.0, math.inf)
    if not (0.0 <= near < far):
        warn(f"{path}: clippingRange {tuple(clip)} is invalid; not clipping")
        near, far = 0.0, math.inf
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), hap, vap, focal, path,
                      lens_radius=lens_radius, focus_distance=focus if lens_radius > 0 else 1.0,
                      clip_near=near, clip_far=far)


# The default camera's view: a three-quarter view from the front-right, above (degrees),
# and the share of the frame the scene's extent may fill in its limiting direction.
DEFAULT_VIEW_AZIMUTH = 45.0
DEFAULT_VIEW_ELEVATION = 30.0
DEFAULT_VIEW_FILL = 0.95


def _default_camera(points: np.ndarray, up_axis: str, resolution: tuple[int, int]) -> CameraDesc:
    """Frames `points` (world space) tightly from a three-quarter view, as usdview's "frame
    all" fits the scene to its view: looking at the centre of their bounds from
    DEFAULT_VIEW_AZIMUTH degrees right of the front (+Z on Y-up stages, -Y on Z-up) and
    DEFAULT_VIEW_ELEVATION above, at the distance where every point projects inside
    DEFAULT_VIEW_FILL of the frame, re-aimed once so the projected extent is centred. A
    50 mm lens with a 24 mm vertical aperture, the horizontal one matching the
    resolution's aspect ratio (so the fit holds for the image rendered)."""
    pts = points if len(points) else np.zeros((1, 3))
    if up_axis == "Z":
        front, up_w = np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    else:
        front, up_w = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    right_w = np.cross(up_w, front)  # +X on both
    az, el = math.radians(DEFAULT_VIEW_AZIMUTH), math.radians(DEFAULT_VIEW_ELEVATION)
    eye_dir = math.cos(el) * (math.cos(az) * front + math.sin(az) * right_w) + math.sin(el) * up_w
    forward = -eye_dir
    right = _unit(np.cross(forward, up_w))
    up = np.cross(right, forward)
    aspect = resolution[0] / resolution[1]
    vap, focal = 24.0, 50.0
    hap = vap * aspect
    tan_w, tan_h = hap / (2 * focal) * DEFAULT_VIEW_FILL, vap / (2 * focal) * DEFAULT_VIEW_FILL
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = (lo + hi) / 2
    size = max(float(np.linalg.norm(hi - lo)), 1e-3)
    q = pts - target
    x, y, z = q @ right, q @ up, q @ forward

    def distance(sx, sy):  # camera distance fitting every point, target shifted by (sx, sy)
        return float(max(np.max(np.abs(x - sx) / tan_w - z), np.max(np.abs(y - sy) / tan_h - z)))

    sx = sy = 0.0
    d = distance(sx, sy)
    depth = np.maximum(d + z, 1e-9)
    u, v = (x - sx) / depth, (y - sy) / depth
    # Centre the projected extent: shift the aim by the middle of the extent at the
    # target's depth, then fit again.
    sx += (u.max() + u.min()) / 2 * d
    sy += (v.max() + v.min()) / 2 * d
    d = max(distance(sx, sy), size * 1e-3)
    origin = target + sx * right + sy * up - forward * d
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), hap, vap, focal,
                      "default camera: three-quarter view framing the scene")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def translate_stage(path: str, frame: float | None = None, *, bundle=None, instancing: str = "flatten",
                    default_light: bool = False, root: str | None = None,
                    camera_relative: bool = True,
                    subdivision_level: int = subdivision.DEFAULT_LEVEL) -> SceneData:
    """Opens a USD file through the bundle sandbox and translates it. `instancing` is
    "flatten" (every instance copied into the flat arrays), "instances" (prototypes +
    instance transforms, prototypes kept out of the flat arrays; the core builds one BVH
    per prototype) or "auto" (instances, unless lights sit inside native-instance
    prototypes: only flattening renders those). With `camera_relative` (the default, and
    what every render uses) the coordinates are the world's less SceneData.world_offset,
    the camera's position, so that float32 holds them as finely as the view needs
    (_move_to_camera); without, they are world coordinates. Raises SceneError with a
    readable message. `subdivision_level` is how many times subdivision surfaces are
    refined (0: their control cage)."""
    from . import bundle as bundle_mod

    if bundle is None:
        bundle = bundle_mod.open_bundle(path, root=root)
    stage = bundle_mod.open_stage(bundle)
    data = translate_opened_stage(stage, frame, bundle=bundle, instancing=instancing,
                                  default_light=default_light, camera_relative=camera_relative,
                                  subdivision_level=subdivision_level)
    data.warnings[:0] = bundle.warnings
    data._bundle = bundle  # keeps an unpack directory (and the textures in it) alive
    return data


def translate_opened_stage(stage, frame: float | None = None, *, bundle=None, instancing: str = "flatten",
                           default_light: bool = False, limits=None, camera_relative: bool = True,
                           subdivision_level: int = subdivision.DEFAULT_LEVEL) -> SceneData:
    from pxr import Usd, UsdGeom

    from .bundle import DEFAULT_LIMITS

    if instancing not in ("flatten", "instances", "auto"):
        raise ValueError(f"instancing must be 'flatten', 'instances' or 'auto', not {instancing!r}")
    if instancing == "auto":
        # Instances render the same as flattening (tests/test_textures_instancing.py) with
        # one exception: lights inside native-instance prototypes, which only flattening
        # keeps. Such scenes are translated again, flattened.
        data = translate_opened_stage(stage, frame, bundle=bundle, instancing="instances",
                                      default_light=default_light, limits=limits, camera_relative=camera_relative,
                                      subdivision_level=subdivision_level)
        if not getattr(data, "_native_prototype_lights", 0):
            return data
        flat = translate_opened_stage(stage, frame, bundle=bundle, instancing="flatten",
                                      default_light=default_light, limits=limits, camera_relative=camera_relative,
                                      subdivision_level=subdivision_level)
        flat.warnings.append("lights inside native instances: the scene was flattened so that they render")
        return flat
    limits = limits or (bundle.limits if bundle is not None else DEFAULT_LIMITS)
    warnings: list[str] = []
    warn = warnings.append
    time = Usd.TimeCode(frame) if frame is not None else Usd.TimeCode.Default()
    if not isinstance(subdivision_level, int) or not 0 <= subdivision_level <= subdivision.MAX_LEVEL:
        raise SceneError(f"subdivision level must be an integer from 0 to {subdivision.MAX_LEVEL}, "
                         f"not {subdivision_level!r}")
    tr = _Translator(stage, time, warn, bundle, limits, instancing, subdivision_level)
    tr.skin()
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate) if instancing == "flatten" \
        else Usd.PrimDefaultPredicate
    tr.walk(Usd.PrimRange.Stage(stage, predicate), None, tr.chunks, top_level=True)
    for type_name, count in sorted(tr.unsupported.items()):
        warn(f"{count} {type_name} prim{'s' if count > 1 else ''} not supported yet; skipped")
    tr.flush_notes()
    if instancing == "flatten" and tr.instanced_triangles > FLATTEN_WARN_TRIANGLES:
        warn(f"instancing was flattened into {tr.instanced_triangles} triangles; "
             f"instancing='instances' keeps one copy per prototype")

    # Camera and resolution: RenderSettings, else the only/first camera, else a default.
    settings = _find_render_settings(stage, warn)
    resolution, from_stage = DEFAULT_RESOLUTION, False
    camera_prim = None
    if settings:
        res = settings.GetResolutionAttr().Get(time)
        if res is not None:
            if res[0] < 1 or res[1] < 1:
                raise SceneError(f"{settings.GetPath()}: resolution {tuple(res)} must be positive")
            resolution, from_stage = (int(res[0]), int(res[1])), True
        targets = settings.GetCameraRel().GetForwardedTargets()
        if targets:
            camera_prim = stage.GetPrimAtPath(targets[0])
            if not camera_prim or not camera_prim.IsA(UsdGeom.Camera):
                raise SceneError(f"{settings.GetPath()}: camera {targets[0]} is not a Camera prim")
    cameras = tr.cameras
    if camera_prim is None and cameras:
        camera_prim = cameras[0]
        if len(cameras) > 1:
            warn(f"{len(cameras)} cameras and no RenderSettings camera; using {camera_prim.GetPath()}")
    up_axis = UsdGeom.GetStageUpAxis(stage)
    if camera_prim is not None:
        camera = _camera_from_prim(camera_prim, tr.xform_cache, time, warn)
    else:
        # Every point (not the chunks' boxes): the fit is to what is seen.
        corners = [c.points for c in tr.chunks if len(c.points)]
        all_instances = np.concatenate(tr.instances) if tr.instances else np.zeros(0, np.uint32)
        if len(all_instances):
            mats = np.concatenate(tr.instance_xforms)
            corners += [_instance_corners(proto["chunks"], mats[all_instances == k])
                        for k, proto in enumerate(tr.prototypes) if any(len(c.points) for c in proto["chunks"])]
        spheres = np.array([row[:4] for row in tr.sphere_lights], np.float64).reshape(-1, 4)
        signs = np.array([(a, b, c) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], np.float64)
        corners += [(spheres[:, None, :3] + spheres[:, None, 3:4] * signs[None]).reshape(-1, 3)]
        bound_pts = np.concatenate(corners) if corners else np.zeros((0, 3))
        camera = _default_camera(bound_pts, up_axis, resolution)
        warn("the scene has no camera: using a default camera, a three-quarter view framing the scene")
    camera_offset = (0.0, 0.0, 0.0)
    if camera_relative:
        _move_to_camera(tr, camera)
        camera_offset = camera.origin
        camera = dataclasses.replace(camera, origin=(0.0, 0.0, 0.0))


    positions, indices, tri_material, normals, uvs = _assemble(tr.chunks)
    sphere_lights = np.array(tr.sphere_lights, dtype=np.float32).reshape(-1, 7)
    rows = tr.materials.rows or [{"values": {**tr.defaults, "diffuseColor": (0.0,) * 3},
                                  "textures": {}, "two_sided": False, "preview": False}]
    albedo = np.array([r["values"]["diffuseColor"] for r in rows], dtype=np.float32).reshape(-1, 3)
    emission = np.array([r["values"]["emissiveColor"] for r in rows], dtype=np.float32).reshape(-1, 3)
    two_sided = np.array([r["two_sided"] for r in rows], dtype=bool)
    params = {"specular_color": np.array([r["values"]["specularColor"] for r in rows], np.float32).reshape(-1, 3)}
    for usd_name, key in _SCALAR_INPUTS.items():
        params[key] = np.array([r["values"][usd_name][0] for r in rows], np.float32)
    params["use_specular_workflow"] = (params["use_specular_workflow"] != 0).astype(np.float32)
    # 1 where the row comes from a UsdPreviewSurface shader; 0 for displayColor, defaults,
    # lights and other shaders. Deliberately not called "preview": the core switches its
    # BSDF on that key, which the lead turns on (tests written for Lambertian walls).
    params["preview_surface"] = np.array([r["preview"] for r in rows], np.float32)
    material_textures = {(m, name): tex for m, r in enumerate(rows) for name, tex in r["textures"].items()}

    prototypes = []
    for proto in tr.prototypes:
        p, i, tm, n, u = _assemble(proto["chunks"])
        prototypes.append({"positions": p, "indices": i, "triangle_material": tm,
                           "shading_normals": n, "uvs": u})
    instances = np.concatenate(tr.instances) if tr.instances else np.zeros(0, np.uint32)
    instance_xforms = np.concatenate(tr.instance_xforms).astype(np.float32) if tr.instance_xforms \
        else np.zeros((0, 4, 4), np.float32)

    distant = np.array(tr.distant_lights, np.float32).reshape(-1, 7)
    if any(len(row) > 6 for row in tr.point_lights):  # shaped lights: every row gets the columns
        tr.point_lights = [row if len(row) > 6 else [*row, *light_shaping.unshaped_columns()]
                           for row in tr.point_lights]
        point = np.array(tr.point_lights, np.float32).reshape(-1, 6 + light_shaping.COLUMNS)
    else:
        point = np.array(tr.point_lights, np.float32).reshape(-1, 6)
    dome = tr.dome_light
    has_light = bool(_emits(rows, tri_material, prototypes) or len(sphere_lights) or len(distant)
                     or len(point) or dome)
    default_lights = None
    if len(indices) == 0 and len(sphere_lights) == 0 and len(instances) == 0:
        warn("the scene has no renderable geometry")
    elif not has_light:
        # Light-less assets are the rule for props and usdz files; viewers light them by
        # default. What to add is recorded here and applied (or not) when the Scene is
        # built, so one translation serves renders with and without it.
        default_lights = default_lighting(camera)
        warn(NO_LIGHT_WARNING)
    data = SceneData(positions=positions, indices=indices, triangle_material=tri_material,
                     albedo=albedo, emission=emission, two_sided_emission=two_sided,
                     sphere_lights=sphere_lights, camera=camera, resolution=resolution,
                     resolution_from_stage=from_stage, warnings=warnings,
                     material_params=params, shading_normals=normals, uvs=uvs,
                     textures=tr.materials.textures, material_textures=material_textures,
                     distant_lights=distant, point_lights=point, dome_light=dome,
                     prototypes=prototypes, instances=instances, instance_transforms=instance_xforms,
                     meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)), up_axis=str(up_axis),
                     world_offset=camera_offset, default_lights=default_lights)
    if default_light:
        apply_default_lighting(data)
    data._native_prototype_lights = tr.native_prototype_lights
    return data


# The one line a light-less stage gets; Scene rewrites it when default lighting is off.
NO_LIGHT_WARNING = ("the scene has no lights: lit by the default lighting (a white dome of radiance "
                    "0.5 and a key light from above and left of the camera; --no-default-light or "
                    "the job setting default_light=false renders it unlit, i.e. black)")
NO_LIGHT_OFF_WARNING = "the scene has no lights and default lighting is off: it renders black"
DEFAULT_DOME_RADIANCE = 0.5
# The key light's illuminance on a surface facing it, and its angular diameter (degrees):
# a white surface facing it reflects E / pi = 0.8 on top of the dome's 0.5.
DEFAULT_KEY_ILLUMINANCE = 0.8 * math.pi
DEFAULT_KEY_ANGLE = 5.0


def default_lighting(camera: CameraDesc) -> dict:
    """What usdview and Quick Look do for a light-less stage, in Tessera's terms: a white
    dome (uniform ambient light, so nothing is black) and one distant key light that comes
    from above, left and behind the camera, so shapes read by their shading. The key
    follows the camera, as a viewer's headlight does."""
    forward, up, right = (np.array(v, np.float64) for v in (camera.forward, camera.up, camera.right))
    toward_light = _unit(-forward + 0.8 * up - 0.6 * right)
    half = math.radians(DEFAULT_KEY_ANGLE) / 2.0
    radiance = DEFAULT_KEY_ILLUMINANCE / (math.pi * math.sin(half) ** 2)
    return {"dome": {"radiance": [DEFAULT_DOME_RADIANCE] * 3, "texture": None,
                     "world_to_light": np.eye(3).tolist(), "path": "default lighting (dome)"},
            "distant": [[*(-toward_light), half, radiance, radiance, radiance]]}


def apply_default_lighting(data: SceneData) -> SceneData:
    """Moves data.default_lights into the light tables (once); returns data."""
    lights = data.default_lights
    if not lights:
        return data
    data.dome_light = lights["dome"]
    data.distant_lights = np.concatenate([np.asarray(data.distant_lights, np.float32).reshape(-1, 7),
                                          np.asarray(lights["distant"], np.float32).reshape(-1, 7)])
    data.default_lights = None
    return data


def _emits(rows: list[dict], tri_material: np.ndarray, prototypes: list[dict]) -> bool:
    """Whether any triangle's material emits: a constant emissiveColor above 0, or an
    emissiveColor texture (whose constant is only its fallback, often 0)."""
    used = set(np.unique(tri_material).tolist())
    for proto in prototypes:
        used.update(np.unique(proto["triangle_material"]).tolist())
    return any(any(c > 0 for c in rows[m]["values"]["emissiveColor"]) or "emissiveColor" in rows[m]["textures"]
               for m in used if m < len(rows))


def _move_to_camera(tr, camera: CameraDesc) -> None:
    """Translates everything the walk put in world space so that the camera sits at the
    origin, in float64 before anything is rounded to float32. float32 holds a coordinate
    to 2^-24 of its magnitude: 1e5 units from the origin that is 0.006, more than a pixel's
    footprint on a subject a few units from the camera. Relative to the camera, a point at
    distance D is held to D 2^-24, far below the pixel footprint at D (D 2 tan(fov/2) / width)
    at any resolution, and rays leave surfaces by about D 1e-6 (the hit points' error
    bounds), so only gaps thinner than that, at that distance, can leak light."""
    shift = np.array(camera.origin, np.float64)
    if not shift.any():
        return
    for c in tr.chunks:
        c.points = c.points - shift
    for row in tr.sphere_lights:
        row[:3] = list(np.asarray(row[:3], np.float64) - shift)
    for row in tr.point_lights:
        row[:3] = list(np.asarray(row[:3], np.float64) - shift)
    for mats in tr.instance_xforms:
        mats[:, 3, :3] -= shift


def _instance_corners(chunks: list, mats: np.ndarray) -> np.ndarray:
    """World bounding-box corners of every instance of a prototype (8 per instance)."""
    lo = np.min([c.points.min(axis=0) for c in chunks if len(c.points)], axis=0)
    hi = np.max([c.points.max(axis=0) for c in chunks if len(c.points)], axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return (np.einsum("vj,njk->nvk", box, mats[:, :3, :3]) + mats[:, None, 3, :3]).reshape(-1, 3)


def _assemble(chunks: list[_Chunk]):
    """Concatenates chunks into flat float32/uint32 arrays. Normals and st are None when no
    chunk has them; chunks without them get face normals (faceted) and st = 0."""
    if not chunks:
        return (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.uint32), None, None)
    counts = np.array([len(c.points) for c in chunks])
    offsets = np.cumsum(counts) - counts
    positions = np.concatenate([c.points for c in chunks]).astype(np.float32)
    indices = np.concatenate([c.tris + o for c, o in zip(chunks, offsets)]).astype(np.uint32)
    tri_material = np.concatenate([c.material for c in chunks]).astype(np.uint32)
    normals = uvs = None
    if any(c.normals is not None for c in chunks):
        normals = np.concatenate([c.normals.astype(np.float32) if c.normals is not None else
                                  np.repeat(_face_normals(c.points, c.tris)[:, None, :], 3, axis=1).astype(np.float32)
                                  for c in chunks])
    if any(c.uvs is not None for c in chunks):
        uvs = np.concatenate([c.uvs.astype(np.float32) if c.uvs is not None else
                              np.zeros((len(c.tris), 3, 2), np.float32) for c in chunks])
    return positions, indices, tri_material, normals, uvs


def _first_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return "; ".join(lines[:3])[:500] if lines else "unknown error"


def _floats(v) -> tuple[float, float, float]:
    return tuple(float(x) for x in v)
