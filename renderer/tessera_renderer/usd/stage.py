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

from collections import Counter
import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import light_shaping, subdivision
from .camera import (CameraDesc, _camera_from_prim, _default_camera, _find_render_settings, _move_to_camera,
                     select_camera)
from .errors import SceneError, local_to_world
from .instancing import InstanceReader, _instance_corners
from .light_links import LightLinks
from .lights import (DEFAULT_LIGHTING_NAME, NO_LIGHT_WARNING, LightReader, _emits, apply_default_lighting,
                     default_lighting)
from .media import media_tables
from .materials import _COLOR_INPUTS, MaterialReader, _MaterialTable, _SCALAR_INPUTS, _as_tuple
from .meshes import _Chunk, MeshReader, _face_normals, _normalized
from .motion import Shutter, MotionReader, render_time, shutter_interval
from .dicing import Dicing
from .scene_data import SceneData
from .volumes import VolumeReader, volume_tables


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


class _Translator(MeshReader, InstanceReader, MaterialReader, LightReader, MotionReader, VolumeReader):
    def __init__(self, stage, time, warn, bundle, limits, instancing: str,
                 subdivision_level: int = subdivision.DEFAULT_LEVEL, shutter: Shutter | None = None):
        from pxr import Sdr, UsdGeom

        self._init_motion(shutter)
        self.stage = stage
        self.subdivision_level = subdivision_level
        self.subdivided_meshes = 0
        self.subdivision_levels: Counter = Counter()
        self.dicing_plan: dict[str, int] | None = None
        self.dicing_without_camera = False
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
        self.ies_tables: list[np.ndarray] = []
        self.curves: dict[str, list[np.ndarray]] = {"points": [], "segments": [], "flags": [], "material": []}
        self.distant_lights: list[list[float]] = []
        # UsdLux light and shadow links (usd/light_links.py), and each light row's link.
        self.light_links = LightLinks(stage)
        self.sphere_light_links: list[int] = []
        self.point_light_links: list[int] = []
        self.distant_light_links: list[int] = []
        self.dome_light: dict | None = None
        # The lights of the core kinds handed over in rows, by kind name (light_readers.py).
        self.light_rows: dict[str, list[list[float]]] = {}
        # UsdLux area lights (emissive triangles of their own): what makes a stage lit,
        # unlike material emission, which is weighed (usd/emission.py).
        self.area_lights = 0
        self.brightest_light: tuple[float, str] | None = None  # (brightness, description)
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
        # UsdVol.Volume prims (usd/volumes.py): translated density grids in walk order, the
        # grids read per (file, grid name), and what of them is not rendered (one warning).
        self.volumes: list[dict] = []
        self.volume_grids_read: dict = {}
        self.volume_unread: set[str] = set()
        self._surface_cache: dict[Any, dict] = {}
        self._geometry_cache: dict[str, Any] = {}
        self._notes: Counter = Counter()  # repeated warnings, reported once with a count
        # Skinned meshes: prim path -> (points in skeleton space at the frame, the
        # skeleton's local-to-world matrix). Filled by skin() before the walk.
        self.skinned: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        # Skinned meshes whose pose changes inside the shutter: path -> posed points at
        # its time steps (T, V, 3), in the skeleton's space.
        self.skinned_steps: dict[str, np.ndarray] = {}
        # Skinned mesh path -> its skeleton's prim, whose transform places (and moves) it.
        self.skinned_skeletons: dict[str, Any] = {}
        # Subdivided meshes: prim path -> their limit points for other cage points, so a
        # deforming one refines each time step's cage (RefinedMesh.limit_points).
        self.subdivision_limits: dict[str, Any] = {}
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
        return local_to_world(self.xform_cache, prim)

    def walk(self, root_range, base_inv: np.ndarray | None, sink: list, top_level: bool) -> None:
        """Translates every renderable prim of a prim range into `sink` as chunks in the
        space `world @ base_inv` (world space when base_inv is None)."""
        from pxr import UsdGeom, UsdLux, UsdVol

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
            if prim.IsA(UsdGeom.Mesh) or type_name in _GPRIMS or prim.IsA(UsdGeom.BasisCurves) or \
                    prim.IsA(UsdGeom.NurbsPatch) or prim.IsA(UsdGeom.Points):
                if prim.IsA(UsdGeom.Mesh):
                    chunk = self.mesh_chunk(prim)
                    if chunk is not None:
                        chunk = self._deformed(prim, chunk, top_level) if skinned is None else \
                            self._skin_deformed(prim, chunk, top_level)
                elif type_name in _GPRIMS:
                    chunk = self.gprim_chunk(prim, type_name)
                elif prim.IsA(UsdGeom.NurbsPatch):
                    chunk = self.nurbs_chunk(prim)
                elif prim.IsA(UsdGeom.Points):
                    chunk = self.points_chunk(prim)
                else:
                    chunk = self.curves_chunk(prim, m if top_level and sink is self.chunks else None)
                if chunk is None:
                    continue
                # Moving during the shutter: an instance of its own, whatever the
                # instancing mode (only an instance's matrices can move in Embree).
                mover = prim if skinned is None else self.skinned_skeletons.get(str(prim.GetPath()))
                mats = self.motion_steps(mover, chunk.points) if top_level and mover is not None else None
                if mats is None and chunk.motion_points is not None:
                    mats = m[None]  # deforming in place: a still instance of a deforming prototype
                if mats is not None:
                    self.add_moving_chunk(chunk, mats, str(prim.GetPath()))
                else:
                    self.emit(chunk.transformed(m), sink, str(prim.GetPath()))
            elif prim.IsA(UsdVol.Volume):
                if not top_level:
                    self._count_note("volumes inside instance prototypes are not supported yet; skipped")
                else:
                    self.add_volume(prim, m)
                it.PruneChildren()  # its fields are read through it
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

    def _deformed(self, prim, chunk: _Chunk, blurrable: bool) -> _Chunk:
        """The mesh's chunk with its points at the shutter's time steps when it deforms
        during the shutter and can be blurred (usd/motion.py); otherwise as it is, with a
        note when it deforms all the same. A subdivided mesh's steps are the limit points
        of each step's cage; its limit normals stay the frame's, as authored normals do."""
        from pxr import UsdGeom

        points = UsdGeom.Mesh(prim).GetPointsAttr()
        if self.shutter is None:
            return chunk
        if not blurrable:
            if self.deforms_during_shutter(points) or self.moves_by_velocities(prim):
                self._count_note("deforming meshes inside instances (points time-sampled within the shutter) "
                                 "are not motion-blurred yet: rendered in their shape at the frame")
            return chunk
        # deforming_points decides whether it deforms (keyed points or velocities), once; a
        # subdivided mesh's chunk holds limit points, so its cage count is read there.
        subdivided = str(prim.GetPath()) in self.subdivision_limits
        steps = self.deforming_points(prim, None if subdivided else len(chunk.points))
        return chunk if steps is None else self._deforming(prim, chunk, steps)

    def _skin_deformed(self, prim, chunk: _Chunk, top_level: bool) -> _Chunk:
        """A skinned mesh's chunk with its posed points at the shutter's time steps when its
        pose changes during the shutter (skin()); a moving skeleton moves it as well (its
        instance follows the skeleton's transform). Subdivided: each step's posed cage
        refined."""
        steps = self.skinned_steps.get(str(prim.GetPath()))
        if steps is None:
            return chunk
        if not top_level:
            self._count_note("skinned meshes inside instances are not motion-blurred yet: rendered in "
                             "their pose at the frame")
            return chunk
        return self._deforming(prim, chunk, steps)

    def _deforming(self, prim, chunk: _Chunk, steps: np.ndarray) -> _Chunk:
        """The chunk deforming through the points `steps` (T, V, 3): a subdivided mesh's are
        its cage's, each refined to the limit surface."""
        limit_points = self.subdivision_limits.get(str(prim.GetPath()))
        if limit_points is not None:
            steps = np.stack([limit_points(step) for step in steps])
        return dataclasses.replace(chunk, motion_points=steps)

    def emit(self, chunk: _Chunk, sink: list, path: str) -> None:
        chunk = self.bind_interiors(chunk, path)
        bad_vertex = ~np.isfinite(chunk.points).all(axis=1)
        if bad_vertex.any():
            keep = ~bad_vertex[chunk.tris].any(axis=1)
            self.warn(f"{path}: {int((~keep).sum())} triangles with NaN/Inf vertices skipped")
            moving = chunk.motion_points
            chunk = _Chunk(np.where(bad_vertex[:, None], 0.0, chunk.points), chunk.tris[keep],
                           chunk.material[keep],
                           chunk.normals[keep] if chunk.normals is not None else None,
                           chunk.uvs[keep] if chunk.uvs is not None else None,
                           None if moving is None else np.where(bad_vertex[None, :, None], 0.0, moving))
        if chunk.uvs is not None and not np.isfinite(chunk.uvs).all():
            bad = ~np.isfinite(chunk.uvs).all(axis=(1, 2))
            self.warn(f"{path}: {int(bad.sum())} triangles with NaN/Inf texture coordinates; their st set to 0")
            uvs = np.where(np.isfinite(chunk.uvs), chunk.uvs, 0.0).astype(chunk.uvs.dtype)
            chunk = dataclasses.replace(chunk, uvs=uvs)
        if chunk.normals is not None:
            n = _normalized(chunk.normals)
            bad = ~np.isfinite(n).all(axis=(1, 2))
            if bad.any():  # zero or non-finite authored normals: faceted there
                n[bad] = _face_normals(chunk.points, chunk.tris[bad])[:, None, :]
            chunk = dataclasses.replace(chunk, normals=n)
        if len(chunk.tris) == 0:
            return
        self.count_primitives(len(chunk.tris), path)
        sink.append(chunk)

    def count_primitives(self, n: int, path: str) -> None:
        """Counts n triangles (or curve segments, which cost Embree about as much) toward
        the scene's triangle limit; past it, a SceneError naming the prim."""
        self.triangles += n
        if self.triangles > self.limits.triangles:
            hint = (f"; its subdivision surfaces are refined {self.subdivision_level} times, a lower "
                    f"subdivision level (0 renders their cages) makes fewer" if self.subdivided_meshes else "")
            raise SceneError(f"{path}: the scene has more than {self.limits.triangles} triangles (limit){hint}")


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


def translate_stage(path: str, frame: float | None = None, *, bundle=None, instancing: str = "flatten",
                    default_light: bool = False, root: str | None = None,
                    camera_relative: bool = True,
                    subdivision_level: int = subdivision.DEFAULT_LEVEL, camera: str | None = None,
                    shutter: tuple[float, float] | None = None,
                    variants: Sequence[tuple[str, str, str]] = (), dicing: Dicing | None = None) -> SceneData:
    """Opens a USD file through the bundle sandbox and translates it. `instancing` is
    "flatten" (every instance copied into the flat arrays), "instances" (prototypes +
    instance transforms, prototypes kept out of the flat arrays; the core builds one BVH
    per prototype) or "auto" (instances, unless lights sit inside native-instance
    prototypes: only flattening renders those). With `camera_relative` (the default, and
    what every render uses) the coordinates are the world's less SceneData.world_offset,
    the camera's position, so that float32 holds them as finely as the view needs
    (_move_to_camera); without, they are world coordinates. Raises SceneError with a
    readable message. `subdivision_level` is how many times subdivision surfaces are
    refined (0: their control cage); with `dicing` (usd/dicing.py) each mesh's level is
    chosen from its size on screen instead (`subdivision_level` then serves only a stage
    without a camera). `camera`, a Camera prim's path, is the camera to render through
    instead of the RenderSettings' (or the first found). `frame` is the time
    code to render (default: the stage's startTimeCode, else the default time); `shutter`
    (open, close), offsets from it in time codes, replaces the camera's shutter:open/close
    (usd/motion.py; (0, 0) renders without motion blur). `variants`, (prim path, variant
    set, variant) each, are selected in place of the stage's own selections (bundle.open_stage)."""
    from . import bundle as bundle_mod

    if bundle is None:
        bundle = bundle_mod.open_bundle(path, root=root)
    stage = bundle_mod.open_stage(bundle, variants)
    data = translate_opened_stage(stage, frame, bundle=bundle, instancing=instancing,
                                  default_light=default_light, camera_relative=camera_relative,
                                  subdivision_level=subdivision_level, camera=camera, shutter=shutter,
                                  dicing=dicing)
    data.warnings[:0] = bundle.warnings
    data._bundle = bundle  # keeps an unpack directory (and the textures in it) alive
    return data


def translate_opened_stage(stage, frame: float | None = None, *, bundle=None, instancing: str = "flatten",
                           default_light: bool = False, limits=None, camera_relative: bool = True,
                           subdivision_level: int = subdivision.DEFAULT_LEVEL,
                           camera: str | None = None, shutter: tuple[float, float] | None = None,
                           dicing: Dicing | None = None) -> SceneData:
    from pxr import Usd, UsdGeom

    from .bundle import DEFAULT_LIMITS

    if instancing not in ("flatten", "instances", "auto"):
        raise ValueError(f"instancing must be 'flatten', 'instances' or 'auto', not {instancing!r}")
    if instancing == "auto":
        # Instances render the same as flattening (tests/renderer/usd/test_textures_instancing.py) with
        # one exception: lights inside native-instance prototypes, which only flattening
        # keeps. Such scenes are translated again, flattened.
        data = translate_opened_stage(stage, frame, bundle=bundle, instancing="instances",
                                      default_light=default_light, limits=limits, camera_relative=camera_relative,
                                      subdivision_level=subdivision_level, camera=camera, shutter=shutter, dicing=dicing)
        if not getattr(data, "_native_prototype_lights", 0):
            return data
        flat = translate_opened_stage(stage, frame, bundle=bundle, instancing="flatten",
                                      default_light=default_light, limits=limits, camera_relative=camera_relative,
                                      subdivision_level=subdivision_level, camera=camera, shutter=shutter, dicing=dicing)
        flat.warnings.append("lights inside native instances: the scene was flattened so that they render")
        return flat
    limits = limits or (bundle.limits if bundle is not None else DEFAULT_LIMITS)
    warnings: list[str] = []
    warn = warnings.append
    time = render_time(stage, frame)
    if not isinstance(subdivision_level, int) or not 0 <= subdivision_level <= subdivision.MAX_LEVEL:
        raise SceneError(f"subdivision level must be an integer from 0 to {subdivision.MAX_LEVEL}, "
                         f"not {subdivision_level!r}")
    # The shutter is the rendering camera's, known before the walk (it decides which prims
    # become moving instances): the same choice select_camera makes after it.
    settings = _find_render_settings(stage, lambda _message: None)
    shutter_interval_ = None
    if not time.IsDefault():
        shutter_camera = select_camera(stage, camera, settings, _visible_cameras(stage, time), lambda _message: None)
        shutter_interval_ = shutter_interval(shutter_camera, time, shutter)
    tr = _Translator(stage, time, warn, bundle, limits, instancing, subdivision_level, shutter_interval_)
    if dicing is not None:
        tr.dicing_plan = _dicing_plan(stage, time, tr, camera, dicing)
    tr.skin()
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate) if instancing == "flatten" \
        else Usd.PrimDefaultPredicate
    tr.walk(Usd.PrimRange.Stage(stage, predicate), None, tr.chunks, top_level=True)
    tr.finish_lights()
    for type_name, count in sorted(tr.unsupported.items()):
        warn(f"{count} {type_name} prim{'s' if count > 1 else ''} not supported yet; skipped")
    if tr.volume_unread:
        warn("volumes: " + ", ".join(sorted(tr.volume_unread)) + " not rendered yet (density only, "
             "docs/media.md)")
    tr.flush_notes()
    if instancing == "flatten" and tr.instanced_triangles > FLATTEN_WARN_TRIANGLES:
        warn(f"instancing was flattened into {tr.instanced_triangles} triangles; "
             f"instancing='instances' keeps one copy per prototype")

    # Resolution from the RenderSettings; the camera requested, else the RenderSettings',
    # else the only/first camera, else a default (select_camera).
    settings = _find_render_settings(stage, warn)
    camera_prim = select_camera(stage, camera, settings, tr.cameras, warn)
    resolution, from_stage = DEFAULT_RESOLUTION, False
    if settings:
        res = settings.GetResolutionAttr().Get(time)
        if res is not None:
            if res[0] < 1 or res[1] < 1:
                raise SceneError(f"{settings.GetPath()}: resolution {tuple(res)} must be positive")
            resolution, from_stage = (int(res[0]), int(res[1])), True
    up_axis = UsdGeom.GetStageUpAxis(stage)
    if camera_prim is not None:
        view = _camera_from_prim(camera_prim, tr.xform_cache, time, warn)
        if tr.shutter is not None and (poses := tr.camera_poses(camera_prim)) is not None:
            view = dataclasses.replace(view, motion=poses)
    else:
        # Every point (not the chunks' boxes): the fit is to what is seen.
        corners = [c.points for c in tr.chunks if len(c.points)]
        corners += [pts[:, :3] + pts[:, 3:4] * s for pts in tr.curves["points"] for s in (-1.0, 1.0)]
        all_instances = np.concatenate(tr.instances) if tr.instances else np.zeros(0, np.uint32)
        if len(all_instances):
            mats = np.concatenate(tr.instance_xforms)
            corners += [_instance_corners(proto["chunks"], mats[all_instances == k])
                        for k, proto in enumerate(tr.prototypes) if any(len(c.points) for c in proto["chunks"])]
        spheres = np.array([row[:4] for row in tr.sphere_lights], np.float64).reshape(-1, 4)
        signs = np.array([(a, b, c) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], np.float64)
        corners += [(spheres[:, None, :3] + spheres[:, None, 3:4] * signs[None]).reshape(-1, 3)]
        bound_pts = np.concatenate(corners) if corners else np.zeros((0, 3))
        view = _default_camera(bound_pts, up_axis, resolution)
        warn("the scene has no camera: using a default camera, a three-quarter view framing the scene")
    camera_offset = (0.0, 0.0, 0.0)
    if camera_relative:
        view = _move_to_camera(tr, view)  # moving camera poses are moved too
        camera_offset = view.origin
        view = dataclasses.replace(view, origin=(0.0, 0.0, 0.0))


    positions, indices, tri_material, normals, uvs = _assemble(tr.chunks)
    sphere_lights = np.array(tr.sphere_lights, dtype=np.float32).reshape(-1, 7)
    rows = tr.materials.rows or [{"values": {**tr.defaults, "diffuseColor": (0.0,) * 3},
                                  "textures": {}, "two_sided": False, "preview": False}]
    albedo = np.array([r["values"]["diffuseColor"] for r in rows], dtype=np.float32).reshape(-1, 3)
    emission = np.array([r["values"]["emissiveColor"] for r in rows], dtype=np.float32).reshape(-1, 3)
    two_sided = np.array([r["two_sided"] for r in rows], dtype=bool)
    material_shaping = None
    if any(r.get("shaping") for r in rows):  # shaped area lights: a shaping row per material
        material_shaping = np.array([r.get("shaping") or light_shaping.unshaped_columns() for r in rows],
                                    np.float32)
    params = {"specular_color": np.array([r["values"]["specularColor"] for r in rows], np.float32).reshape(-1, 3)}
    for usd_name, key in _SCALAR_INPUTS.items():
        params[key] = np.array([r["values"][usd_name][0] for r in rows], np.float32)
    params["use_specular_workflow"] = (params["use_specular_workflow"] != 0).astype(np.float32)
    # 1 where the row comes from a UsdPreviewSurface shader; 0 for displayColor, defaults,
    # lights and other shaders. Deliberately not called "preview": the core switches its
    # BSDF on that key, which the lead turns on (tests written for Lambertian walls).
    params["preview_surface"] = np.array([r["preview"] for r in rows], np.float32)
    material_textures = {(m, name): tex for m, r in enumerate(rows) for name, tex in r["textures"].items()}
    if any(r.get("tint") for r in rows):
        params["transmission_tint"] = np.array([r.get("tint") or (1.0, 1.0, 1.0) for r in rows], np.float32)
    used_rows = set(np.unique(tri_material).tolist())
    used_rows.update(r for proto in tr.prototypes for c in proto["chunks"] for r in np.unique(c.material).tolist())
    used_rows.update(r for m in tr.curves["material"] for r in np.unique(m).tolist())
    media_rows, material_media = media_tables(rows, used_rows)
    grid_media, interface_only = [], None
    if tr.volumes:
        # Each volume's box: a pure medium interface of its own (its row names its medium,
        # numbered after the homogeneous media of absorbing glass).
        first = 0 if media_rows is None else len(media_rows)
        grid_media, boxes = volume_tables(tr.volumes, np.asarray(camera_offset, np.float64), first)
        material_media = np.concatenate([np.full((len(rows), 2), -1, np.int32) if material_media is None
                                         else np.asarray(material_media, np.int32).reshape(-1, 2),
                                         np.full((len(boxes), 2), -1, np.int32)])
        interface_only = np.zeros(len(rows) + len(boxes), bool)
        extra_p, extra_i, extra_m = [positions.reshape(-1, 3)], [indices.reshape(-1, 3)], [tri_material]
        base = len(positions.reshape(-1, 3))
        for corners, tris, medium in boxes:
            row = len(albedo)
            albedo = np.r_[albedo, np.zeros((1, 3), np.float32)]
            emission = np.r_[emission, np.zeros((1, 3), np.float32)]
            two_sided = np.r_[two_sided, False]
            for key in params:
                params[key] = np.r_[params[key], params[key][:1] * 0]
            material_media[row, 0] = medium
            interface_only[row] = True
            extra_p.append(corners.astype(np.float32))
            extra_i.append(tris + np.uint32(base))
            extra_m.append(np.full(len(tris), row, np.uint32))
            base += len(corners)
        positions = np.concatenate(extra_p).astype(np.float32)
        indices = np.concatenate(extra_i).astype(np.uint32)
        tri_material = np.concatenate(extra_m).astype(np.uint32)
        if normals is not None:
            normals = np.concatenate([normals, _face_normals(positions, indices[-12 * len(boxes):])[:, None, :]
                                      .repeat(3, axis=1)]).astype(normals.dtype)
        if uvs is not None:
            uvs = np.concatenate([uvs, np.zeros((12 * len(boxes), 3, 2), uvs.dtype)])
        if material_shaping is not None:
            material_shaping = np.r_[material_shaping, np.repeat(material_shaping[:1] * 0, len(boxes), axis=0)]

    prototypes = []
    for proto in tr.prototypes:
        p, i, tm, n, u = _assemble(proto["chunks"])
        prototypes.append({"positions": p, "indices": i, "triangle_material": tm,
                           "shading_normals": n, "uvs": u})
        steps = [c.motion_points for c in proto["chunks"]]
        if any(s is not None for s in steps):  # a deforming prim's prototype: its one chunk
            steps = np.asarray(steps[0], np.float32)
            prototypes[-1].update(positions=steps[0], motion_positions=steps[1:])
    instances = np.concatenate(tr.instances) if tr.instances else np.zeros(0, np.uint32)
    instance_xforms = np.concatenate(tr.instance_xforms).astype(np.float32) if tr.instance_xforms \
        else np.zeros((0, 4, 4), np.float32)
    motion_instances, motion_time_steps, motion_transforms = tr.motion_tables()
    light_motion = dict(zip(("light_motion_kinds", "light_motion_indices", "light_motion_time_steps",
                             "light_motion_transforms"), tr.light_motion_tables()))

    distant = np.array(tr.distant_lights, np.float32).reshape(-1, 7)
    if any(len(row) > 6 for row in tr.point_lights):  # shaped lights: every row gets the columns
        tr.point_lights = [row if len(row) > 6 else [*row, *light_shaping.unshaped_columns()]
                           for row in tr.point_lights]
        point = np.array(tr.point_lights, np.float32).reshape(-1, 6 + light_shaping.COLUMNS)
    else:
        point = np.array(tr.point_lights, np.float32).reshape(-1, 6)
    dome = tr.dome_light
    light_rows = {kind: np.array(rows, np.float32).reshape(len(rows), -1) for kind, rows in tr.light_rows.items()}
    has_light = bool(tr.area_lights or len(sphere_lights) or len(distant) or len(point) or dome or
                     any(len(rows) for rows in light_rows.values()))
    emission_note = None
    if not has_light and _emits(rows, tri_material, prototypes):
        has_light, emission_note = _emission_lights(tr, rows, positions, indices, tri_material, prototypes,
                                                    instances, instance_xforms, sphere_lights)
    default_lights = None
    if len(indices) == 0 and len(sphere_lights) == 0 and len(instances) == 0 and not tr.curves["segments"]:
        warn("the scene has no renderable geometry")
    elif not has_light:
        # Light-less assets are the rule for props and usdz files; viewers light them by
        # default. What to add is recorded here and applied (or not) when the Scene is
        # built, so one translation serves renders with and without it.
        default_lights = default_lighting(view)
        warn(NO_LIGHT_WARNING)
        if emission_note:
            warn(emission_note)
    brightest = tr.brightest_light[1] if tr.brightest_light else None
    if default_lights is not None:
        brightest = DEFAULT_LIGHTING_NAME
    elif brightest is None and has_light:
        brightest = "the scene's emissive materials (no UsdLux light)"
    data = SceneData(positions=positions, indices=indices, triangle_material=tri_material,
                     albedo=albedo, emission=emission, two_sided_emission=two_sided,
                     sphere_lights=sphere_lights, camera=view, resolution=resolution,
                     resolution_from_stage=from_stage, warnings=warnings,
                     material_params=params, shading_normals=normals, uvs=uvs,
                     textures=tr.materials.textures, material_textures=material_textures,
                     distant_lights=distant, point_lights=point, dome_light=dome, light_rows=light_rows,
                     prototypes=prototypes, instances=instances, instance_transforms=instance_xforms,
                     meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)), up_axis=str(up_axis),
                     world_offset=camera_offset, default_lights=default_lights, brightest_light=brightest,
                     motion_instances=motion_instances, motion_time_steps=motion_time_steps, **light_motion,
                     material_shaping=material_shaping,
                     ies_tables=np.stack(tr.ies_tables) if tr.ies_tables else None,
                     curves=_curve_arrays(tr.curves), media=media_rows, material_media=material_media,
                     light_links=_light_link_arrays(tr, rows),
                     motion_transforms=motion_transforms,
                     time_code=None if time.IsDefault() else float(time.GetValue()),
                     shutter=None if tr.shutter is None else (tr.shutter.open, tr.shutter.close),
                     animated=stage_is_animated(stage), grid_media=grid_media,
                     material_interface_only=interface_only)
    if default_light:
        apply_default_lighting(data)
    data._native_prototype_lights = tr.native_prototype_lights
    data.subdivision_summary = _subdivision_summary(tr, data, dicing)
    return data


def _dicing_plan(stage, time, tr, camera: str | None, dicing: Dicing) -> dict[str, int] | None:
    """Levels per mesh path for the camera the render will use (select_camera's choice,
    made before the walk as for the shutter), or None without a camera: the default view
    is fitted to the refined geometry, so it cannot decide the refinement."""
    from . import dicing as dicing_mod

    quiet = lambda _message: None  # noqa: E731  (the walk's own choice warns)
    settings = _find_render_settings(stage, quiet)
    prim = select_camera(stage, camera, settings, _visible_cameras(stage, time), quiet)
    if prim is None:
        tr.dicing_without_camera = True  # said by the first subdivision mesh, if any
        return None
    resolution = dicing.resolution
    res = settings.GetResolutionAttr().Get(time) if settings else None
    if resolution is None:
        resolution = (int(res[0]), int(res[1])) if res is not None and min(res) >= 1 else DEFAULT_RESOLUTION
    view = _camera_from_prim(prim, tr.xform_cache, time, quiet)
    return dicing_mod.plan(stage, time, tr.xform_cache, view, dicing, tuple(resolution), tr.instancing,
                           tr._count_note)


def _subdivision_summary(tr, data: SceneData, dicing: Dicing | None) -> str | None:
    """One line for the render log: how subdivision surfaces were refined, the triangles
    stored and the bytes the translated geometry holds."""
    if not tr.subdivided_meshes:
        return None
    arrays = [data.positions, data.indices, data.triangle_material, data.shading_normals, data.uvs]
    arrays += [a for proto in data.prototypes for a in proto.values()]
    nbytes = sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))
    stored = len(data.indices) + sum(len(proto["indices"]) for proto in data.prototypes)
    levels = ", ".join(f"{n} at level {lv}" for lv, n in sorted(tr.subdivision_levels.items()))
    how = (f"diced at {dicing.rate:g} px (maximum level {dicing.max_level}, {dicing.memory_mb:g} MB budget)"
           if getattr(tr, "dicing_plan", None) is not None else "fixed level")
    meshes = f"{tr.subdivided_meshes} mesh{'es' if tr.subdivided_meshes != 1 else ''}"
    return (f"subdivision: {meshes} {how}: {levels}; {stored} triangles stored, "
            f"{nbytes / 2 ** 20:.1f} MB of geometry")


def stage_is_animated(stage) -> bool:
    """Whether a layer the stage uses holds time samples. Without any no attribute varies
    with time (skinning, velocities and the camera all read time samples), so every frame
    renders the same image. Value clips count: the stage lists their clip layers among the
    used ones from the moment it opens."""
    return any(layer.ListAllTimeSamples() for layer in stage.GetUsedLayers())


def _emission_lights(tr, rows, positions, indices, tri_material, prototypes, instances, instance_xforms,
                     sphere_lights) -> tuple[bool, str | None]:
    """(whether the stage's material emission lights it, the line saying why not). The
    rule (docs/scene-translation.md): measured emitted power against what the default
    lighting would deliver to the scene's bounding sphere."""
    from . import emission
    from .lights import DEFAULT_DOME_RADIANCE, DEFAULT_KEY_ILLUMINANCE

    meshes = [(positions, indices, tri_material, np.ones(1))]
    for k, proto in enumerate(prototypes):
        mats = np.asarray(instance_xforms, np.float64)[np.asarray(instances) == k]
        if len(mats):
            scales = np.abs(np.linalg.det(mats[:, :3, :3])) ** (2.0 / 3.0)
            meshes.append((proto["positions"], proto["indices"], proto["triangle_material"], scales))
    power, count = emission.emitted_power(rows, tr.materials.textures, meshes)
    corners = [np.asarray(positions, np.float64).reshape(-1, 3)]
    corners += [_instance_corners(proto["chunks"], np.asarray(instance_xforms, np.float64)[np.asarray(instances) == k])
                for k, proto in enumerate(tr.prototypes)
                if (np.asarray(instances) == k).any() and any(len(c.points) for c in proto["chunks"])]
    corners += [np.asarray(sphere_lights, np.float64)[:, :3]]
    pts = np.concatenate(corners)
    radius = 0.5 * float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 0.0
    reference = emission.default_lighting_power(radius, DEFAULT_DOME_RADIANCE, DEFAULT_KEY_ILLUMINANCE)
    if reference > 0 and power >= emission.EMISSION_LIGHTS_FRACTION * reference:
        return True, None
    if power <= 0:
        return False, None  # provably zero: nothing to say beyond the light-less line
    share = power / reference if reference > 0 else 0.0
    return False, (f"the scene's only emission ({count} triangles of emissive materials, power {power:.4g}) is "
                   f"{100 * share:.2g} % of what the default lighting gives it ({reference:.4g}), below "
                   f"the {100 * emission.EMISSION_LIGHTS_FRACTION:.0f} % that counts as lighting: "
                   f"{emission.EMISSION_DEFAULT_LIT}")


def _visible_cameras(stage, time) -> list:
    """The Camera prims the walk will meet (visible, top level), in its order."""
    from pxr import Usd, UsdGeom

    found = []
    it = iter(Usd.PrimRange.Stage(stage, Usd.PrimDefaultPredicate))
    for prim in it:
        imageable = UsdGeom.Imageable(prim)
        if imageable and (imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible or
                          imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)):
            it.PruneChildren()
        elif prim.IsInstance() or prim.IsA(UsdGeom.PointInstancer):
            it.PruneChildren()
        elif prim.IsA(UsdGeom.Camera):
            found.append(prim)
    return found


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


def _light_link_arrays(tr, rows: list[dict]) -> dict[str, np.ndarray] | None:
    """SceneData.light_links: the link table and who uses which link and group, or None
    when no light has links."""
    if not tr.light_links:
        return None
    illuminates, shadows = tr.light_links.tables()
    return {"illuminates": illuminates, "shadows": shadows,
            "material_group": np.array([r.get("link_group", 0) for r in rows], np.uint32),
            "material_light": np.array([r.get("light_link", -1) for r in rows], np.int32),
            "sphere": np.array(tr.sphere_light_links, np.int32),
            "point": np.array(tr.point_light_links, np.int32),
            "distant": np.array(tr.distant_light_links, np.int32),
            "dome": np.array([tr.dome_light.get("link", -1) if tr.dome_light else -1], np.int32)}


def _curve_arrays(curves: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray] | None:
    """The walk's native curves as SceneData.curves (float32 once camera-relative)."""
    if not curves["segments"]:
        return None
    return {"points": np.concatenate(curves["points"]).astype(np.float32),
            "segments": np.concatenate(curves["segments"]).astype(np.uint32),
            "flags": np.concatenate(curves["flags"]).astype(np.uint8),
            "material": np.concatenate(curves["material"]).astype(np.uint32)}

