"""Tessera's renderer: USD in, float RGBA tiles out. Knows nothing of Redis or HTTP.

    scene = load_scene("scene.usda")
    rgba = scene.render_tile(0, 0, 64, 64, width=512, height=512, spp=64, seed=0)
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from . import _core
from .usd import (NO_LIGHT_OFF_WARNING, NO_LIGHT_WARNING, SceneData, SceneError, apply_default_lighting,
                  translate_stage)
from .usd.emission import EMISSION_DEFAULT_LIT, EMISSION_UNLIT

__all__ = ["Scene", "SceneError", "load_scene", "NonFiniteSampleError", "AOV_NAMES", "integrators"]

log = logging.getLogger("tessera.renderer")

# Per-pixel outputs render_tile can return besides RGBA (docs/aovs.md).
AOV_NAMES = ("albedo", "normal", "depth", "spp", "variance")

# Below this UsdPreviewSurface roughness a metal or clearcoat reflects sharply enough to
# form caustics that path tracing finds only by chance (see docs/integrators.md).
AUTO_SMOOTH_ROUGHNESS = 0.3


def integrators() -> list[dict]:
    """The core's registered integrators, in registry order (the first is the default):
    dicts of name, description, capabilities (splats, scene_passes, stop_per_tile,
    complete, delta_caustics) and params (extra setting -> description). See registry.py."""
    return [dict(i) for i in _core.integrators()]


class NonFiniteSampleError(RuntimeError):
    """A sample came out NaN or Inf: a renderer bug, reported with where it happened."""


class Scene:
    """A translated scene with its BVH built, ready to render tiles of any size."""

    def __init__(self, data: SceneData, default_light: bool = True, light_selection: str = "auto"):
        """`default_light`: light a stage that has no light with the default lighting
        (usd.lights.default_lighting, announced in the warnings); off, it renders black.
        `light_selection`: how next event estimation picks a light: "auto" (a light BVH
        weighing position and orientation once the scene has 16 or more still area
        emitters, by power below that), "power" or "bvh" (docs/lights.md)."""
        # What a render with default lighting off would warn (the pre-flight reports it).
        self.lit_by_default = bool(default_light and getattr(data, "default_lights", None))
        self.unlit_warnings = _with_default_lighting(data, False).warnings if self.lit_by_default else None
        data = _with_default_lighting(data, default_light)
        self.data = data
        try:
            # Light tables added to SceneData later are optional here: absent means none.
            point = getattr(data, "point_lights", None)
            distant = getattr(data, "distant_lights", None)
            dome = getattr(data, "dome_light", None)
            textures = _texture_tables(data)
            extras = {**textures, **_instance_tables(data, with_uvs=bool(textures)), **_light_motion_tables(data)}
            shaping = getattr(data, "material_shaping", None)
            if shaping is not None:
                extras["material_shaping"] = np.ascontiguousarray(shaping, np.float32)
            ies = getattr(data, "ies_tables", None)
            if ies is not None:
                extras["ies_tables"] = np.ascontiguousarray(ies, np.float32)
            curves = getattr(data, "curves", None)
            if curves is not None:
                extras.update(curve_points=np.ascontiguousarray(curves["points"], np.float32).reshape(-1, 4),
                              curve_segments=np.ascontiguousarray(curves["segments"], np.uint32),
                              curve_flags=np.ascontiguousarray(curves["flags"], np.uint8),
                              curve_material=np.ascontiguousarray(curves["material"], np.uint32))
            extras.update(_media_tables(data))
            links = getattr(data, "light_links", None)
            if links is not None:
                extras["light_links"] = {k: np.ascontiguousarray(v) for k, v in links.items()}
            light_rows = {kind: np.ascontiguousarray(rows, np.float32) for kind, rows in
                          (getattr(data, "light_rows", None) or {}).items() if len(rows)}
            if light_rows:
                extras["light_rows"] = light_rows
            uvs = getattr(data, "uvs", None)
            if uvs is not None and len(uvs) and extras.get("texture_table") is not None:
                extras["uvs"] = np.ascontiguousarray(uvs, dtype=np.float32).reshape(-1, 3, 2)
            self._core = _core.Scene(data.positions.reshape(-1, 3), data.indices.reshape(-1, 3),
                                     data.triangle_material, data.albedo.reshape(-1, 3),
                                     data.emission.reshape(-1, 3), data.two_sided_emission,
                                     data.sphere_lights.reshape(-1, 7),
                                     _rows(point, 6 if point is None or len(point) == 0
                                           else np.asarray(point).shape[1]), _rows(distant, 7),
                                     tuple(float(x) for x in dome["radiance"]) if dome else (0.0, 0.0, 0.0),
                                     *_preview_table(getattr(data, "material_params", None),
                                                     len(data.albedo.reshape(-1, 3))),
                                     *_dome_texture(dome),
                                     _corner_normals(getattr(data, "shading_normals", None)), **extras,
                                     # only when asked: benchmarks load older _core builds side by side
                                     **({} if light_selection == "auto" else {"light_selection": light_selection}))
        except ValueError as exc:
            raise SceneError(f"invalid scene: {exc}") from None

    @property
    def width(self) -> int:
        return self.data.resolution[0]

    @property
    def height(self) -> int:
        return self.data.resolution[1]

    @property
    def warnings(self) -> list[str]:
        return self.data.warnings

    @property
    def num_triangles(self) -> int:
        return self._core.num_triangles

    @property
    def num_curve_segments(self) -> int:
        """Segments of the Embree round curves (still BasisCurves of the world)."""
        return self._core.num_curve_segments

    @property
    def num_linked_lights(self) -> int:
        """Lights whose UsdLux light or shadow link leaves some surface out."""
        return self._core.num_linked_lights

    @property
    def has_media(self) -> bool:
        """Some material bounds a participating medium (absorbing glass, docs/media.md)."""
        return self._core.has_media

    @property
    def num_emitters(self) -> int:
        return self._core.num_emitters

    @property
    def texture_bytes(self) -> int:
        """Bytes of texels the core holds: every image whole, as float, with its mip-maps."""
        return self._core.texture_bytes

    @property
    def uses_light_bvh(self) -> bool:
        """Whether next event estimation chooses area emitters through the light BVH."""
        return self._core.uses_light_bvh

    @property
    def splat_exponent(self) -> int:
        """Splats are fixed point in units of 2^splat_exponent, chosen from the lights'
        power so that any emission scale fits (tessera_base.film.resolve_splats)."""
        return self._core.splat_exponent

    @property
    def has_motion(self) -> bool:
        """Something moves during the shutter: each camera sample then draws its instant."""
        return self._core.has_motion

    @property
    def num_instances(self) -> int:
        return self._core.num_instances

    @property
    def num_stored_triangles(self) -> int:
        """Triangles held in memory: the world mesh plus one copy of each prototype."""
        return self._core.num_stored_triangles

    def resolve_integrator(self, name: str) -> str:
        """`auto` -> the core's choice (its AutoIntegrator rule reads the capabilities: the
        first complete integrator, one with delta_caustics if the scene needs it) given
        whether the scene has delta-light caustics (has_delta_caustics). A pure function of
        the scene, so every worker resolves it the same way. Other names pass through."""
        if name != "auto":
            return name
        if self.has_media:
            # Only integrators that handle media accept a scene with them (docs/media.md).
            return next(i["name"] for i in integrators() if i["complete"] and i.get("handles_media"))
        return _core.auto_integrator(self.has_delta_caustics())

    def kind_without_light_paths(self) -> str | None:
        """A light kind in the scene that cannot start light paths (portal), or None: the
        integrators that trace them (traces_light_paths) refuse the scene."""
        return self._core.kind_without_light_paths

    def has_delta_surfaces(self) -> bool:
        """Some material may have a delta lobe (a smooth mirror, clear glass): where photon
        merging (vcm, sppm) earns its cost, and where sppm aims its photons."""
        return bool(self._core.has_delta_surfaces)

    def has_delta_caustics(self) -> bool:
        """Whether a delta light (point, or distant with angle 0) can shine through or off a
        material that forms caustics (transmission, or a metal/clearcoat smoother than
        AUTO_SMOOTH_ROUGHNESS): path tracing cannot find those paths at all. Where it is
        false, path tracing measured more efficient per unit time even on a caustic scene
        lit by an area light (docs/benchmarks/integrators.md)."""
        point = getattr(self.data, "point_lights", None)
        distant = getattr(self.data, "distant_lights", None)
        has_delta_light = (point is not None and len(point) > 0) or \
            (distant is not None and len(distant) > 0 and bool(np.any(np.asarray(distant)[:, 3] == 0.0)))
        if not has_delta_light:
            return False
        params = getattr(self.data, "material_params", None) or {}
        flags = params.get("preview_surface")
        if flags is None:
            return False
        preview = np.asarray(flags, bool).reshape(-1)
        opacity = np.asarray(params["opacity"], np.float32).reshape(-1)
        threshold = np.asarray(params["opacity_threshold"], np.float32).reshape(-1)
        roughness = np.asarray(params["roughness"], np.float32).reshape(-1)
        metallic = np.asarray(params["metallic"], np.float32).reshape(-1)
        clearcoat = np.asarray(params["clearcoat"], np.float32).reshape(-1)
        coat_roughness = np.asarray(params["clearcoat_roughness"], np.float32).reshape(-1)
        used = np.zeros(len(preview), bool)
        used[np.unique(self.data.triangle_material)] = True
        for proto in getattr(self.data, "prototypes", None) or []:
            used[np.unique(proto["triangle_material"])] = True
        transmits = (opacity < 1.0) & (threshold == 0.0)  # < 0: presence, passes straight
        smooth = ((roughness < AUTO_SMOOTH_ROUGHNESS) & (metallic > 0.0)) | \
                 ((clearcoat > 0.0) & (coat_roughness < AUTO_SMOOTH_ROUGHNESS))
        return bool(np.any(preview & used & (transmits | smooth)))

    def camera(self, width: int, height: int) -> "_core.Camera":
        c = self.data.camera
        half_w, half_h, shift_x, shift_y = c.window(width, height)
        return _core.Camera(c.origin, c.right, c.up, c.forward, half_w, half_h, width, height,
                            lens_radius=c.lens_radius, focal_distance=c.focus_distance, near=c.clip_near,
                            far=c.clip_far, shift_x=shift_x, shift_y=shift_y,
                            orthographic=getattr(c, "orthographic", False),
                            motion=None if getattr(c, "motion", None) is None
                            else np.asarray(c.motion, np.float32).reshape(-1, 12))

    def check_integrator(self, integrator: str, *, max_depth: int = 64,
                         integrator_params: dict[str, float] | None = None) -> None:
        """ValueError if `integrator` refuses these settings' values on this scene (a render
        would fail the same way, after its set-up): for checking a job before it starts."""
        _core.check_integrator(self._core, self.resolve_integrator(integrator), max_depth,
                               {k: float(v) for k, v in (integrator_params or {}).items()})

    def scene_pass(self, integrator: str, iteration: int, *, seed: int = 0, max_depth: int = 64,
                   threads: int = 0, integrator_params: dict[str, float] | None = None) -> bytes:
        """The product of the scene-wide pass of `iteration` of `integrator` (one whose
        entry has scene_passes; resolved, not `auto`): bytes every tile of that iteration
        is rendered with (render_tile's scene_product). A pure function of the scene, the
        integrator and its params, the seed and the iteration. Releases the GIL."""
        return _core.scene_pass(self._core, integrator, iteration, seed, max_depth, threads,
                                {k: float(v) for k, v in (integrator_params or {}).items()})

    def render_tile(self, x0: int, y0: int, w: int, h: int, *, width: int | None = None,
                    height: int | None = None, spp: int = 64, seed: int = 0, max_depth: int = 64,
                    threads: int = 0, sample_start: int = 0, return_variance: bool = False,
                    integrator: str | None = None, splats: np.ndarray | None = None,
                    sampler: str = "sobol", aovs=(), stats: dict | None = None,
                    integrator_params: dict[str, float] | None = None,
                    scene_product: bytes | None = None, camera: "_core.Camera | None" = None,
                    batch_splats: np.ndarray | None = None, batch_rgb: np.ndarray | None = None,
                    camera_window: tuple[int, int, int, int] | None = None):
        """Renders pixels [x0, x0+w) x [y0, y0+h) of a width x height image, averaging samples
        [sample_start, sample_start + spp) of each pixel. Returns float32 linear RGBA of shape
        (h, w, 4); with return_variance, (rgba, variance) where variance is float32 (h, w, 3),
        the per-channel sample variance (divide by spp for the variance of the mean).
        integrator: a name from integrators() (default: the first) or "auto";
        integrator_params: the extra settings its entry's params declare. An integrator that
        splats also adds the tile's light-path splats to `splats`, an int64 (height, width,
        3) full-frame buffer (see film.py for turning it into an image); an integrator with
        scene_passes renders from `scene_product`, its scene pass's (`scene_pass`); the tile traced
        w * h * spp light paths. sampler: "sobol" (Owen-scrambled, default) or
        "independent".

        aovs: names from AOV_NAMES (albedo, normal, depth, spp, variance; docs/aovs.md).
        With any, returns (rgba, {name: array}) instead: albedo and normal float32 (h, w, 3),
        depth and spp float32 (h, w), variance (h, w, 3); return_variance then adds
        "variance" to the dict. `stats`, if given, is filled with the renderer's counters
        (samples, closest_rays, shadow_rays, ...).

        batch_splats (int64 (K, height, width, 3)) and batch_rgb (float32 (K, h, w, 3)): a
        splatting integrator's K variance batches, made in this same pass. The samples are
        split as convergence.batch_ranges splits them; batch k's splats are added to
        batch_splats[k] as well as to `splats`, and its camera mean is written to
        batch_rgb[k], each what a render of that range alone gives, bit for bit. Releases
        the GIL.

        camera_window (x0, y0, x1, y1; x1, y1 exclusive): a crop. Pixels outside it come out 0
        in every output and splats landing outside it are dropped; a splatting integrator
        still traces their light paths (their splats may land inside), so the window's
        pixels equal a render without it bit for bit, and bdpt and vcm skip the camera
        subpaths outside it (docs/aovs.md, "Crop")."""
        width = width or self.width
        height = height or self.height
        window = None
        if camera_window is not None:
            wx0, wy0, wx1, wy1 = (int(v) for v in camera_window)
            if not (0 <= wx0 < wx1 and 0 <= wy0 < wy1):
                raise ValueError(f"camera_window {wx0},{wy0},{wx1},{wy1} is not (x0, y0, x1, y1) with "
                                 "0 <= x0 < x1 and 0 <= y0 < y1")
            window = (wx0, wy0, wx1 - wx0, wy1 - wy0)
        integrator = self.resolve_integrator(integrator or _core.integrators()[0]["name"])
        aovs = [aovs] if isinstance(aovs, str) else list(aovs)
        unknown = [a for a in aovs if a not in AOV_NAMES]
        if unknown:
            raise ValueError(f"unknown AOV {unknown[0]!r} (known: {', '.join(AOV_NAMES)})")
        want_variance = return_variance or "variance" in aovs
        core_aovs = [a for a in aovs if a != "variance"]
        # camera: another view than the scene's (the radiosity preview moves it), built
        # for this width and height.
        camera = camera if camera is not None else self.camera(width, height)
        rgba, info = _core.render_tile(self._core, camera, x0, y0, w, h,
                                       spp, seed, max_depth, threads, sample_start, want_variance,
                                       integrator, splats, sampler, core_aovs,
                                       {k: float(v) for k, v in (integrator_params or {}).items()},
                                       scene_product, batch_splats, batch_rgb,
                                       window)
        if stats is not None:
            stats.update({k: v for k, v in info.items() if not isinstance(v, np.ndarray)})
        if info["rejected_splats"]:
            raise NonFiniteSampleError(f"{info['rejected_splats']} NaN/Inf/negative splats in tile "
                                       f"({x0},{y0},{w}x{h}) (seed {seed})")
        if info["nonfinite_samples"]:
            x, y, s = info["first_nonfinite"]
            raise NonFiniteSampleError(
                f"{info['nonfinite_samples']} NaN/Inf samples in tile ({x0},{y0},{w}x{h}); "
                f"first at pixel ({x},{y}) sample {s} (seed {seed})")
        if aovs:
            out = {name: info[name] for name in core_aovs}
            if want_variance:
                out["variance"] = info["variance"]
            return rgba, out
        return (rgba, info["variance"]) if return_variance else rgba


def _with_default_lighting(data: SceneData, on: bool) -> SceneData:
    """A shallow copy of a light-less stage's data with its default lights applied (on)
    or its warning saying it renders black (off); other data as it is."""
    if not getattr(data, "default_lights", None):
        return data
    import dataclasses

    extra = {k: v for k, v in vars(data).items() if k.startswith("_")}  # bundle, blob files
    copy = dataclasses.replace(data, warnings=list(data.warnings))
    copy.__dict__.update(extra)
    if on:
        return apply_default_lighting(copy)
    copy.warnings = [NO_LIGHT_OFF_WARNING if w == NO_LIGHT_WARNING else
                     w.replace(EMISSION_DEFAULT_LIT, EMISSION_UNLIT) for w in copy.warnings]
    copy.default_lights = None
    return copy


# Column order of the core's UsdPreviewSurface table (renderer/python/module.cpp).
_PREVIEW_COLUMNS = ("metallic", "roughness", "ior", "clearcoat", "clearcoat_roughness", "opacity",
                    "opacity_threshold", "use_specular_workflow")


def _preview_table(params: dict | None, rows: int):
    """(params (M, 14), mask (M,)) for materials that are UsdPreviewSurfaces (marked by
    params["preview_surface"]); other rows (displayColor, no material) are Lambertian."""
    if not params or "preview_surface" not in params or rows == 0:
        return None, None
    table = np.zeros((rows, 14), dtype=np.float32)
    table[:, 0:3] = np.asarray(params["specular_color"], np.float32).reshape(rows, 3)
    for k, name in enumerate(_PREVIEW_COLUMNS):
        table[:, 3 + k] = np.asarray(params[name], np.float32).reshape(rows)
    if "transmission_tint" in params:  # stored as 1 - tint: zeros are clear glass
        table[:, 11:14] = 1.0 - np.asarray(params["transmission_tint"], np.float32).reshape(rows, 3)
    return table, np.asarray(params["preview_surface"], bool).reshape(rows)


# Order of the core's texture slots (renderer/core/scene/scene.h TextureSlot).
TEXTURE_SLOTS = ("diffuseColor", "emissiveColor", "specularColor", "metallic", "roughness", "clearcoat",
                 "clearcoatRoughness", "opacity", "ior", "normal")
_WRAP_CODES = {"repeat": 0, "useMetadata": 0, "clamp": 1, "mirror": 2, "black": 3}
_OUTPUT_CODES = {"r": 0, "g": 1, "b": 2, "a": 3, "rgb": 4}


def _load_image(path: str) -> np.ndarray | None:
    """float32 (h, w, channels <= 4) texels of an image file, rows top to bottom, or None.
    Read here, once per scene, with OpenImageIO (already the translation's image reader),
    so the C++ core never parses image files."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        oiio.geterror()
        return None
    pixels = buf.get_pixels(oiio.FLOAT)
    if pixels is None or buf.has_error:
        return None
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return np.ascontiguousarray(pixels[:, :, :4])


def _udim_tiles(tex: dict) -> list[tuple[int, str]]:
    """(tile index 0..99, file) of a UDIM texture's tiles (1001 + u + 10 v)."""
    import glob
    import re

    pattern = tex["file"]
    files = tex.get("udim_files") or sorted(glob.glob(pattern.replace("<UDIM>", "1[0-9][0-9][0-9]")))
    head, _, tail = os.path.basename(pattern).partition("<UDIM>")
    rx = re.compile(re.escape(head) + r"(1\d\d\d)" + re.escape(tail) + "$")
    tiles = []
    for f in files:
        m = rx.match(os.path.basename(f))
        if m and 0 <= int(m.group(1)) - 1001 < 100:
            tiles.append((int(m.group(1)) - 1001, f))
    return tiles


def _media_tables(data) -> dict:
    """The core's participating-media arguments (docs/media.md), none without media."""
    out = {}
    grids = getattr(data, "grid_media", None)
    if grids:
        out["grid_media"] = [(np.ascontiguousarray(d, np.float32), np.ascontiguousarray(w, np.float32),
                              np.ascontiguousarray(c, np.float32)) for d, w, c in grids]
    if getattr(data, "media", None) is not None:
        out["media"] = np.ascontiguousarray(data.media, np.float32).reshape(-1, 7)
    for key, dtype in (("material_media", np.int32), ("material_interface_only", bool)):
        value = getattr(data, key, None)
        if value is not None:
            out[key] = np.ascontiguousarray(value, dtype)
    if "material_media" in out:
        out["material_media"] = out["material_media"].reshape(-1, 2)
    return out


def _texture_tables(data) -> dict:
    """The core's texture arguments for SceneData.textures / material_textures: each image
    file decoded once (shared by every texture reading it), a parameter row per texture,
    UDIM tile maps, and a texture index per (material, input). An image that cannot be read
    leaves its texture on the fallback, with a warning."""
    textures = getattr(data, "textures", None) or []
    bindings = getattr(data, "material_textures", None) or {}
    rows = len(np.asarray(data.albedo).reshape(-1, 3))
    if not textures or not bindings or rows == 0:
        return {}
    images: list[np.ndarray] = []
    srgb: list[bool] = []
    index: dict[tuple[str, bool], int] = {}

    def image(path: str, is_srgb: bool) -> int:
        key = (str(path), is_srgb)
        if key not in index:
            pixels = _load_image(path)
            if pixels is None:
                data.warnings.append(f"texture {path!r} cannot be read; its textures use their fallback")
                log.warning("texture %s cannot be read; using the fallback", path)
                index[key] = -1
            else:
                index[key] = len(images)
                images.append(pixels)
                srgb.append(is_srgb)
        return index[key]

    table = np.zeros((len(textures), 22), np.float32)
    tiles = np.full((len(textures), 100), -1, np.int32)
    for k, tex in enumerate(textures):
        is_srgb = str(tex.get("color_space", "raw")).lower() == "srgb"
        if tex.get("udim") or "<UDIM>" in str(tex["file"]):
            table[k, 0], table[k, 1] = -1, 1
            for tile, f in _udim_tiles(tex):
                tiles[k, tile] = image(f, is_srgb)
        else:
            table[k, 0] = image(tex["file"], is_srgb)
        table[k, 2] = _WRAP_CODES.get(tex.get("wrap_s", "useMetadata"), 0)
        table[k, 3] = _WRAP_CODES.get(tex.get("wrap_t", "useMetadata"), 0)
        table[k, 4:8] = tex.get("scale", (1, 1, 1, 1))
        table[k, 8:12] = tex.get("bias", (0, 0, 0, 0))
        table[k, 12:16] = tex.get("fallback", (0, 0, 0, 1))
        table[k, 16] = _OUTPUT_CODES.get(tex.get("channel", "rgb"), 4)
        xf = tex.get("transform2d") or {}
        table[k, 17:19] = xf.get("scale", (1.0, 1.0))
        table[k, 19] = xf.get("rotation", 0.0)
        table[k, 20:22] = xf.get("translation", (0.0, 0.0))
    slots = np.full((rows, len(TEXTURE_SLOTS)), -1, np.int32)
    for (m, name), t in bindings.items():
        if name in TEXTURE_SLOTS and 0 <= m < rows:
            slots[m, TEXTURE_SLOTS.index(name)] = t
    return {"images": images, "image_srgb": np.array(srgb, bool), "texture_table": table,
            "texture_tiles": tiles, "material_textures": slots}


def _instance_tables(data, with_uvs: bool) -> dict:
    """The core's instancing arguments: prototypes (flat arrays in their own space) and one
    transform per instance. Empty when the scene was flattened."""
    instances = getattr(data, "instances", None)
    if instances is None or len(instances) == 0:
        return {}
    protos = []
    for p in data.prototypes:
        normals = p.get("shading_normals")
        uvs = p.get("uvs") if with_uvs else None
        positions = np.ascontiguousarray(p["positions"], np.float32).reshape(-1, 3)
        steps = p.get("motion_positions")  # a deforming prototype's further time steps
        protos.append((positions,
                       np.ascontiguousarray(p["indices"], np.uint32).reshape(-1, 3),
                       np.ascontiguousarray(p["triangle_material"], np.uint32).reshape(-1),
                       None if normals is None else np.ascontiguousarray(normals, np.float32).reshape(-1, 3, 3),
                       None if uvs is None else np.ascontiguousarray(uvs, np.float32).reshape(-1, 3, 2),
                       None if steps is None or len(steps) == 0 else
                       np.ascontiguousarray(steps, np.float32).reshape(-1, len(positions), 3)))
    tables = {"prototypes": protos,
              "instance_prototype": np.ascontiguousarray(instances, np.uint32).reshape(-1),
              "instance_transforms": np.ascontiguousarray(data.instance_transforms, np.float32).reshape(-1, 4, 4)}
    moving = getattr(data, "motion_instances", None)
    if moving is not None and len(moving):
        tables.update(motion_instances=np.ascontiguousarray(moving, np.uint32).reshape(-1),
                      motion_time_steps=np.ascontiguousarray(data.motion_time_steps, np.uint32).reshape(-1),
                      motion_transforms=np.ascontiguousarray(data.motion_transforms, np.float32).reshape(-1, 4, 4))
    return tables


def _light_motion_tables(data) -> dict:
    """The core's moving-light arguments (SceneData.light_motion_*); empty when none move."""
    kinds = getattr(data, "light_motion_kinds", None)
    if kinds is None or len(kinds) == 0:
        return {}
    return {"light_motion_kinds": np.ascontiguousarray(kinds, np.uint8).reshape(-1),
            "light_motion_indices": np.ascontiguousarray(data.light_motion_indices, np.uint32).reshape(-1),
            "light_motion_time_steps": np.ascontiguousarray(data.light_motion_time_steps, np.uint32).reshape(-1),
            "light_motion_transforms": np.ascontiguousarray(data.light_motion_transforms,
                                                            np.float32).reshape(-1, 4, 4)}


def _corner_normals(normals) -> np.ndarray | None:
    if normals is None or len(normals) == 0:
        return None
    return np.ascontiguousarray(normals, dtype=np.float32).reshape(-1, 3, 3)


def _dome_texture(dome: dict | None):
    """(texels float32 (h, w, 3), world_to_light (3, 3)) of a textured dome, else (None, None).
    The path was checked by the sandbox when the scene was translated."""
    if not dome or not dome.get("texture"):
        return None, None
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(dome["texture"]))
    if buf.has_error:
        raise SceneError(f"dome texture {dome['texture']}: {buf.geterror()}")
    pixels = np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.shape[2] < 3:  # grey: replicate
        pixels = np.repeat(pixels[:, :, :1], 3, axis=2)
    rgb = np.ascontiguousarray(np.nan_to_num(pixels[:, :, :3], nan=0.0, posinf=0.0, neginf=0.0).clip(min=0.0))
    rotation = np.ascontiguousarray(np.asarray(dome.get("world_to_light", np.eye(3)), np.float32).reshape(3, 3))
    return rgb, rotation


def _rows(table, columns: int) -> np.ndarray:
    if table is None or len(table) == 0:
        return np.zeros((0, columns), dtype=np.float32)
    return np.ascontiguousarray(table, dtype=np.float32).reshape(-1, columns)


def load_scene(path: str | Path, frame: float | None = None, *, root: str | Path | None = None,
               instancing: str = "auto", default_light: bool = True,
               subdivision_level: int | None = None, camera: str | None = None,
               shutter: tuple[float, float] | None = None, variants=(), dicing=None) -> Scene:
    """Reads a bundle (.usda/.usdc/.usd, .usdz or .zip) through the sandbox and builds it.
    For a loose layer, `root` (default: its directory) is the bundle every asset must stay
    in; `root="/"` trusts the local filesystem (what `tessera render` does by default). `instancing`: "auto" (default: Embree instances, one BVH per prototype, unless
    lights sit inside native-instance prototypes), "instances" or "flatten" (every
    instance copied). `default_light`: a stage without any light (emissive geometry
    counts as light) gets the default lighting, announced in one warning; off, it renders
    black. `subdivision_level`: how many times subdivision surfaces are refined (default
    tessera_renderer.usd.subdivision.DEFAULT_LEVEL; 0 renders their control cage). `dicing`:
    a tessera_renderer.usd.dicing.Dicing (rate in pixels, maximum level, memory budget,
    resolution) choosing each mesh's level from its size in the camera, when
    `subdivision_level` is None.
    `camera`: the path of the Camera prim to render through (default: the RenderSettings'
    camera, else the first camera, else a default view). `frame`: the time code to render
    (default: the stage's startTimeCode, else the default time); `shutter`: (open, close)
    offsets from it in time codes, in place of the camera's shutter:open/close ((0, 0): no
    motion blur; docs/motion.md). `variants`: (prim path, variant set, variant) selections in
    place of the stage's own. Raises SceneError for bad input."""
    from .usd.subdivision import DEFAULT_LEVEL

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file not found: {path}")
    data = translate_stage(str(path), frame, root=None if root is None else str(root),
                           instancing=instancing,
                           subdivision_level=DEFAULT_LEVEL if subdivision_level is None else subdivision_level,
                           camera=camera, shutter=shutter, variants=tuple(variants),
                           dicing=dicing if subdivision_level is None else None)
    scene = Scene(data, default_light=default_light)
    for w in scene.warnings:
        log.warning("%s: %s", path.name, w)
    return scene
