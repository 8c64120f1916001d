"""USD stage -> flat arrays for the C++ core.

Reads a stage with `pxr` (usd-core), flattens every visible UsdGeomMesh to world-space
triangles, maps UsdPreviewSurface `diffuseColor`/`emissiveColor` to a material table, turns
UsdLux RectLight and SphereLight into emitters, and finds the camera and resolution
(UsdRenderSettings first). Mesh work is vectorised with numpy; Python loops run per prim,
never per vertex.

Conventions (documented in docs/scene-translation.md):
- Light radiance = color * intensity * 2^exposure, divided by the light's world-space area
  when `normalize` is on: intensity 1 seen head-on gives pixel value 1.
- RectLight is centred in its local XY plane and emits along local -Z, one-sided.
- Emissive meshes emit on the side their winding faces; on both sides when `doubleSided`.
- Camera apertures and focal length share a unit, so only their ratio matters; the aperture
  is expanded to the image's aspect ratio (UsdRenderSettings' default conform policy).
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np


class SceneError(Exception):
    """The scene cannot be rendered; the message says why, for the person who sent it."""


DEFAULT_RESOLUTION = (512, 512)

# Prim types that carry no geometry of their own: traversed without a warning.
_STRUCTURAL_TYPES = {
    "", "Xform", "Scope", "Material", "Shader", "NodeGraph", "GeomSubset", "Camera",
    "RenderSettings", "RenderProduct", "RenderVar", "RenderPass", "Mesh", "RectLight",
    "SphereLight",
}


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
    """Everything the core needs, as plain arrays."""

    positions: np.ndarray           # float32 (V, 3), world space
    indices: np.ndarray             # uint32 (T, 3)
    triangle_material: np.ndarray   # uint32 (T,)
    albedo: np.ndarray              # float32 (M, 3)
    emission: np.ndarray            # float32 (M, 3)
    two_sided_emission: np.ndarray  # bool (M,)
    sphere_lights: np.ndarray       # float32 (S, 7): centre, radius, radiance
    camera: CameraDesc
    resolution: tuple[int, int]
    resolution_from_stage: bool
    warnings: list[str] = field(default_factory=list)


class _MaterialTable:
    """Deduplicates (albedo, emission, two-sided) rows."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []
        self._index: dict[tuple, int] = {}

    def add(self, albedo, emission, two_sided: bool) -> int:
        key = (tuple(float(x) for x in albedo), tuple(float(x) for x in emission), bool(two_sided))
        if key not in self._index:
            self._index[key] = len(self.rows)
            self.rows.append(key)
        return self._index[key]


class _Translator:
    def __init__(self, stage, time, warn):
        from pxr import Sdr, UsdGeom

        self.stage = stage
        self.time = time
        self.warn = warn
        self.xform_cache = UsdGeom.XformCache(time)
        self.materials = _MaterialTable()
        self.positions: list[np.ndarray] = []
        self.indices: list[np.ndarray] = []
        self.tri_material: list[np.ndarray] = []
        self.sphere_lights: list[list[float]] = []
        self.vertex_count = 0
        self._surface_cache: dict[str, tuple] = {}
        self._notes: Counter = Counter()  # repeated warnings, reported once with a count
        node = Sdr.Registry().GetShaderNodeByIdentifier("UsdPreviewSurface")
        # UsdPreviewSurface defaults come from its registered definition, not from here.
        self.default_diffuse = tuple(node.GetShaderInput("diffuseColor").GetDefaultValue())
        self.default_emissive = tuple(node.GetShaderInput("emissiveColor").GetDefaultValue())

    # -- geometry -------------------------------------------------------------------
    def world_matrix(self, prim) -> np.ndarray:
        """4x4 float64, USD's row-vector convention: p_world = [p, 1] @ M."""
        return np.array(self.xform_cache.GetLocalToWorldTransform(prim), dtype=np.float64)

    def add_triangles(self, points_world: np.ndarray, tris: np.ndarray, material: int) -> None:
        self.positions.append(points_world.astype(np.float32))
        self.indices.append((tris + self.vertex_count).astype(np.uint32))
        self.tri_material.append(np.full(len(tris), material, dtype=np.uint32))
        self.vertex_count += len(points_world)

    def add_mesh(self, prim) -> None:
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh(prim)
        path = str(prim.GetPath())
        points = mesh.GetPointsAttr().Get(self.time)
        counts = mesh.GetFaceVertexCountsAttr().Get(self.time)
        face_indices = mesh.GetFaceVertexIndicesAttr().Get(self.time)
        if points is None or counts is None or face_indices is None or len(points) == 0:
            self.warn(f"{path}: mesh has no points or faces; skipped")
            return
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(counts, dtype=np.int64)
        face_indices = np.asarray(face_indices, dtype=np.int64)
        if np.any(counts < 0) or counts.sum() != len(face_indices):
            raise SceneError(f"{path}: faceVertexCounts sum to {int(counts.sum())} but there are "
                             f"{len(face_indices)} faceVertexIndices")
        if len(face_indices) and (face_indices.min() < 0 or face_indices.max() >= len(points)):
            raise SceneError(f"{path}: faceVertexIndices reference vertex "
                             f"{int(face_indices.max() if face_indices.max() >= len(points) else face_indices.min())}"
                             f" but the mesh has {len(points)} points")
        if np.any(counts < 3):
            self.warn(f"{path}: {int(np.count_nonzero(counts < 3))} faces with fewer than 3 vertices skipped")

        tris = _triangulate_fan(counts, face_indices)
        if UsdGeom.Mesh(prim).GetOrientationAttr().Get(self.time) == UsdGeom.Tokens.leftHanded:
            tris = tris[:, ::-1]

        m = self.world_matrix(prim)
        world = points @ m[:3, :3] + m[3, :3]
        if np.linalg.det(m[:3, :3]) < 0:  # a mirroring transform flips the winding
            tris = tris[:, ::-1]
        bad_vertex = ~np.isfinite(world).all(axis=1)
        if bad_vertex.any():
            keep = ~bad_vertex[tris].any(axis=1)
            self.warn(f"{path}: {int((~keep).sum())} triangles with NaN/Inf vertices skipped")
            tris = tris[keep]
            world = np.where(bad_vertex[:, None], 0.0, world)
        if len(tris) == 0:
            return
        if mesh.GetSubdivisionSchemeAttr().Get(self.time) not in (None, UsdGeom.Tokens.none):
            self._count_note("meshes with a subdivisionScheme are rendered as their flat control cage")

        albedo, emission = self.surface_of(prim)
        double_sided = bool(mesh.GetDoubleSidedAttr().Get(self.time))
        self.add_triangles(world, tris, self.materials.add(albedo, emission, double_sided))

    # -- materials ------------------------------------------------------------------
    def surface_of(self, prim) -> tuple[tuple, tuple]:
        from pxr import UsdGeom, UsdShade

        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not material:
            color = UsdGeom.Gprim(prim).GetDisplayColorAttr().Get(self.time)
            if color is not None and len(color) > 0:
                return self._clamped_albedo(tuple(color[0]), str(prim.GetPath())), (0.0, 0.0, 0.0)
            return self.default_diffuse, (0.0, 0.0, 0.0)
        key = str(material.GetPath())
        if key not in self._surface_cache:
            self._surface_cache[key] = self._read_preview_surface(material)
        return self._surface_cache[key]

    def _read_preview_surface(self, material) -> tuple[tuple, tuple]:
        path = str(material.GetPath())
        shader, _, _ = material.ComputeSurfaceSource()
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            ident = shader.GetIdAttr().Get() if shader else None
            self.warn(f"{path}: surface is {ident or 'missing'}, not UsdPreviewSurface; using the default grey")
            return self.default_diffuse, (0.0, 0.0, 0.0)
        diffuse = self._input_value(shader, "diffuseColor", self.default_diffuse, path)
        emissive = self._input_value(shader, "emissiveColor", self.default_emissive, path)
        return self._clamped_albedo(diffuse, path), _non_negative(emissive)

    def _input_value(self, shader, name, default, path):
        inp = shader.GetInput(name)
        if not inp:
            return default
        for attr in inp.GetValueProducingAttributes():
            if attr.GetName().startswith("outputs:"):  # driven by a texture or node graph
                self._count_note(f"texture or shader-network inputs are not evaluated yet "
                                 f"({name} of {path} uses its fallback)")
                return default
            value = attr.Get(self.time)
            if value is not None:
                return tuple(value)
        return default

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
    def light_radiance(self, prim, area: float) -> np.ndarray:
        from pxr import UsdLux

        light = UsdLux.LightAPI(prim)
        color = np.array(light.GetColorAttr().Get(self.time) or (1.0, 1.0, 1.0), dtype=np.float64)
        intensity = light.GetIntensityAttr().Get(self.time)
        exposure = light.GetExposureAttr().Get(self.time)
        radiance = color * (1.0 if intensity is None else intensity) * 2.0 ** (exposure or 0.0)
        if light.GetEnableColorTemperatureAttr().Get(self.time):
            self.warn(f"{prim.GetPath()}: colour temperature is not applied yet")
        if light.GetNormalizeAttr().Get(self.time):
            radiance = radiance / area
        if not np.isfinite(radiance).all() or (radiance < 0).any():
            raise SceneError(f"{prim.GetPath()}: light radiance {radiance.tolist()} must be finite and >= 0")
        return radiance

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
        tris = np.array([[0, 1, 2], [0, 2, 3]])
        if np.linalg.det(m[:3, :3]) < 0:
            tris = tris[:, ::-1]
        area = float(np.linalg.norm(np.cross(world[1] - world[0], world[3] - world[0])))
        if not (area > 0.0) or not np.isfinite(world).all():
            self.warn(f"{prim.GetPath()}: RectLight has no area; skipped")
            return
        radiance = self.light_radiance(prim, area)
        self.add_triangles(world, tris, self.materials.add((0.0, 0.0, 0.0), radiance, False))

    def add_sphere_light(self, prim) -> None:
        from pxr import UsdLux

        sphere = UsdLux.SphereLight(prim)
        radius = float(sphere.GetRadiusAttr().Get(self.time) or 0.0)
        m = self.world_matrix(prim)
        scales = np.linalg.norm(m[:3, :3], axis=1)
        if not np.allclose(scales, scales[0], rtol=1e-4):
            self.warn(f"{prim.GetPath()}: non-uniform scale on a SphereLight; using the mean scale")
        radius *= float(scales.mean())
        if sphere.GetTreatAsPointAttr().Get(self.time):
            self.warn(f"{prim.GetPath()}: treatAsPoint is not supported yet; rendered as a sphere")
        if not (radius > 0.0) or not math.isfinite(radius):
            self.warn(f"{prim.GetPath()}: SphereLight has no radius; skipped")
            return
        radiance = self.light_radiance(prim, 4.0 * math.pi * radius * radius)
        center = m[3, :3]
        self.sphere_lights.append([*center, radius, *radiance])

    # -- bookkeeping ----------------------------------------------------------------
    def _count_note(self, message: str) -> None:
        self._notes[message] += 1

    def flush_notes(self) -> None:
        for message, count in self._notes.items():
            self.warn(message + (f" ({count} prims)" if count > 1 else ""))


def _non_negative(color) -> tuple:
    c = tuple(float(x) for x in color)
    if not all(math.isfinite(x) for x in c):
        return (0.0, 0.0, 0.0)
    return tuple(max(x, 0.0) for x in c)


def _triangulate_fan(counts: np.ndarray, face_indices: np.ndarray) -> np.ndarray:
    """Fan-triangulates polygons: face with n vertices -> n-2 triangles (v0, vk, vk+1).
    Faces with fewer than 3 vertices yield nothing. Vectorised over all faces."""
    starts = np.cumsum(counts) - counts
    n_tris = np.maximum(counts - 2, 0)
    total = int(n_tris.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64)
    face_start = np.repeat(starts, n_tris)
    first_tri = np.cumsum(n_tris) - n_tris
    k = np.arange(total) - np.repeat(first_tri, n_tris) + 1
    return np.stack([face_indices[face_start], face_indices[face_start + k],
                     face_indices[face_start + k + 1]], axis=1)


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
    focal = float(cam.GetFocalLengthAttr().Get(time) or 50.0)
    hap = float(cam.GetHorizontalApertureAttr().Get(time) or 20.955)
    vap = float(cam.GetVerticalApertureAttr().Get(time) or 15.2908)
    path = str(prim.GetPath())
    if not all(math.isfinite(v) and v > 0 for v in (focal, hap, vap)):
        raise SceneError(f"{path}: focalLength and apertures must be positive "
                         f"(got {focal}, {hap}, {vap})")
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
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), hap, vap, focal, path)


def _default_camera(positions: np.ndarray, sphere_lights: np.ndarray, up_axis: str) -> CameraDesc:
    """Frames the bounding sphere of the geometry from the front (+Z for Y-up stages,
    -Y for Z-up), 50 mm lens on a 36 x 24 mm aperture."""
    pts = positions if len(positions) else np.zeros((1, 3))
    if len(sphere_lights):
        pts = np.concatenate([pts, sphere_lights[:, :3]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    if up_axis == "Z":
        forward, up = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    else:
        forward, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    half_fov = math.atan(24.0 / (2 * 50.0))  # the narrower (vertical) half angle
    distance = radius / math.sin(half_fov) * 1.05
    origin = center - forward * distance
    right = np.cross(forward, up)
    return CameraDesc(_floats(origin), _floats(right), _floats(up), _floats(forward), 36.0, 24.0, 50.0,
                      "default camera framing the scene bounds")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def translate_stage(path: str, frame: float | None = None) -> SceneData:
    """Opens and translates a USD file. Raises SceneError with a readable message."""
    from pxr import Tf, Usd, UsdGeom, UsdLux

    warnings: list[str] = []
    warn = warnings.append
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise SceneError(f"cannot read USD file {path.__str__().rsplit('/', 1)[-1]}: "
                         f"{_first_line(str(exc))}") from None
    if stage is None:
        raise SceneError(f"cannot read USD file {path}")
    time = Usd.TimeCode(frame) if frame is not None else Usd.TimeCode.Default()
    tr = _Translator(stage, time, warn)
    unsupported: Counter = Counter()
    cameras = []

    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        imageable = UsdGeom.Imageable(prim)
        if imageable:
            if imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible or \
                    imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                it.PruneChildren()
                continue
        type_name = prim.GetTypeName()
        if prim.IsA(UsdGeom.Mesh):
            tr.add_mesh(prim)
        elif prim.IsA(UsdLux.RectLight):
            tr.add_rect_light(prim)
        elif prim.IsA(UsdLux.SphereLight):
            tr.add_sphere_light(prim)
        elif prim.IsA(UsdGeom.Camera):
            cameras.append(prim)
        elif type_name not in _STRUCTURAL_TYPES:
            unsupported[type_name] += 1
    for type_name, count in sorted(unsupported.items()):
        warn(f"{count} {type_name} prim{'s' if count > 1 else ''} not supported yet; skipped")
    tr.flush_notes()

    positions = np.concatenate(tr.positions) if tr.positions else np.zeros((0, 3), np.float32)
    indices = np.concatenate(tr.indices) if tr.indices else np.zeros((0, 3), np.uint32)
    tri_material = np.concatenate(tr.tri_material) if tr.tri_material else np.zeros(0, np.uint32)
    sphere_lights = np.array(tr.sphere_lights, dtype=np.float32).reshape(-1, 7)
    rows = tr.materials.rows or [((0.0,) * 3, (0.0,) * 3, False)]
    albedo = np.array([r[0] for r in rows], dtype=np.float32)
    emission = np.array([r[1] for r in rows], dtype=np.float32)
    two_sided = np.array([r[2] for r in rows], dtype=bool)
    if len(indices) == 0 and len(sphere_lights) == 0:
        warn("the scene has no renderable geometry")
    elif not (emission.any() or len(sphere_lights)):
        warn("the scene has no lights: it renders black")

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
    if camera_prim is None and cameras:
        camera_prim = cameras[0]
        if len(cameras) > 1:
            warn(f"{len(cameras)} cameras and no RenderSettings camera; using {camera_prim.GetPath()}")
    if camera_prim is not None:
        camera = _camera_from_prim(camera_prim, tr.xform_cache, time, warn)
    else:
        camera = _default_camera(positions, sphere_lights, UsdGeom.GetStageUpAxis(stage))
        warn("the scene has no camera: using a default camera framing its bounds")

    return SceneData(positions=np.ascontiguousarray(positions, np.float32),
                     indices=np.ascontiguousarray(indices, np.uint32),
                     triangle_material=np.ascontiguousarray(tri_material, np.uint32),
                     albedo=albedo, emission=emission, two_sided_emission=two_sided,
                     sphere_lights=sphere_lights, camera=camera, resolution=resolution,
                     resolution_from_stage=from_stage, warnings=warnings)


def _first_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return "; ".join(lines[:3])[:500] if lines else "unknown error"


def _floats(v) -> tuple[float, float, float]:
    return tuple(float(x) for x in v)
