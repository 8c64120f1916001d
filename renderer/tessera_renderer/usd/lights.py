"""UsdLux lights -> emissive triangles, point, sphere, distant and dome lights, and the
default lighting of a light-less stage (the LightReader part of the translator)."""
from __future__ import annotations

import math
import numpy as np

from .. import _core
from . import gprims, light_shaping
from . import portal_light  # noqa: F401  (registers its reader)
from .camera import CameraDesc, _unit
from .errors import SceneError, read_float, read_floats
from .light_readers import READERS, reads, row_columns
from .authoring import authoring_layer
from .meshes import _Chunk
from .scene_data import SceneData


class LightReader:
    """Translates every UsdLux light kind, in the units of docs/scene-translation.md."""

    # -- lights ---------------------------------------------------------------------
    def light_radiance(self, prim, area: float | None) -> np.ndarray:
        from pxr import UsdLux

        light = UsdLux.LightAPI(prim)
        t = self.time
        color = read_floats(light.GetColorAttr(), t, (1.0, 1.0, 1.0))
        intensity = read_float(light.GetIntensityAttr(), t, 1.0)
        exposure = read_float(light.GetExposureAttr(), t, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):  # refused below when not finite
            radiance = color * intensity * np.exp2(exposure)
        if light.GetEnableColorTemperatureAttr().Get(t):
            kelvin = read_float(light.GetColorTemperatureAttr(), t, 6500.0) or 6500.0
            radiance = radiance * gprims.blackbody_rgb(kelvin)
        if area is not None and light.GetNormalizeAttr().Get(t):
            radiance = radiance / area
        if not np.isfinite(radiance).all() or (radiance < 0).any():
            raise SceneError(f"{prim.GetPath()}: light radiance {radiance.tolist()} must be finite and >= 0")
        # What a black image's warning names: the light its author made brightest.
        brightness = float(intensity * 2.0 ** exposure * (color @ np.array([0.2126, 0.7152, 0.0722])))
        if self.brightest_light is None or brightness > self.brightest_light[0]:
            where = f"{prim.GetPath()} ({prim.GetTypeName()}, intensity {intensity:g}" + \
                (f", exposure {exposure:g}" if exposure else "") + ")"
            self.brightest_light = (brightness, where)
        return radiance

    def add_light(self, prim, type_name: str) -> None:
        """The registered reader of the prim's UsdLux schema (usd/light_readers.py) adds it."""
        entry = READERS.get(type_name)
        if entry is None:
            self.unsupported[type_name or "untyped light"] += 1
            return
        before = (len(self.sphere_lights), len(self.point_lights), len(self.distant_lights), self.dome_light)
        entry.read(self, prim)
        # Each light row of a kind gets its link, kept aligned with the kind's rows.
        link = self.light_links.link_of(prim.GetPath())
        for rows, links in ((self.sphere_lights, self.sphere_light_links), (self.point_lights, self.point_light_links),
                            (self.distant_lights, self.distant_light_links)):
            links.extend([link] * (len(rows) - len(links)))
        if self.dome_light is not None and "link" not in self.dome_light:
            self.dome_light["link"] = link
        if type_name in ("SphereLight", "DistantLight", "DomeLight"):
            self._add_light_motion(prim, type_name, before)

    def add_light_row(self, kind: str, row) -> None:
        """A light of a core kind handed over in rows (light_readers.py): `row` as the
        kind's file in renderer/core/lights/ lays it out, its first three columns a position."""
        columns = row_columns(kind)
        if len(row) != columns:
            raise ValueError(f"a {kind} light row has {columns} columns, not {len(row)}")
        self.light_rows.setdefault(kind, []).append([float(x) for x in row])

    def finish_lights(self) -> None:
        """The registered readers' checks across lights, after the walk."""
        for entry in READERS.values():
            if entry.finish is not None:
                entry.finish(self)

    def _add_light_motion(self, prim, type_name: str, before) -> None:
        """A sphere, point, distant or dome light that moves during the shutter: its rigid
        motion relative to where it stands at the frame (what the handler just added), at
        steps chosen as for any moving prim (usd/motion.py) on a box of the light's size."""
        spheres, points, distants, dome = before
        if len(self.sphere_lights) > spheres:
            kind, index, size = light_kind_number("sphere"), spheres, self.sphere_lights[-1][3]
        elif len(self.point_lights) > points:
            kind, index, size = light_kind_number("point"), points, 1.0
        elif len(self.distant_lights) > distants:
            kind, index, size = light_kind_number("distant"), distants, 1.0
        elif self.dome_light is not None and dome is None:
            kind, index, size = light_kind_number("dome"), 0, 1.0
        else:
            return  # skipped
        # The tolerance is relative to the light's size around where it stands at the frame.
        here = np.eye(4)
        here[3, :3] = -self.world_matrix(prim)[3, :3]
        box = np.array([[x, y, z] for x in (-size, size) for y in (-size, size) for z in (-size, size)])
        mats = self.motion_steps(prim, box, base_inv=here)
        if mats is None:
            return
        frame = self.world_matrix(prim)
        deltas = np.linalg.inv(frame) @ (mats @ np.linalg.inv(here))  # row vectors: p(t) = p(frame) @ delta
        # Rigid: the nearest rotation to each step's linear part (a light's scale is the frame's).
        u, _, vt = np.linalg.svd(deltas[:, :3, :3])
        deltas[:, :3, :3] = u @ vt
        if (np.linalg.det(deltas[:, :3, :3]) < 0).any():
            self.warn(f"{prim.GetPath()}: a light mirrored during the shutter is not motion-blurred")
            return
        self.light_motion.append((kind, index, deltas))


    def _emissive(self, prim, local_pts, tris, radiance, two_sided=False, texture=None, uvs=None,
                  shaped=None) -> None:
        """Emitting triangles of an area light (in its own space), of `radiance`, or of
        radiance x the texture's texel at the corners' st `uvs` (T, 3, 2). `shaped`: its
        ShapingAPI (light_shaping) shapes the emission about the emitting normal ("normal":
        flat lights, whose normal is their -Z) or about the light's -Z ("axis": a cylinder,
        whose normals turn around it)."""
        self.area_lights += 1
        m = self.world_matrix(prim)
        surface = {"values": {**self.defaults, "diffuseColor": (0.0, 0.0, 0.0),
                              "emissiveColor": tuple(float(x) for x in radiance)}, "textures": {}}
        columns = light_shaping.shaping_columns(self, prim) if shaped else None
        if columns is not None:
            if shaped == "axis":
                columns[0] = light_shaping.ABOUT_AXIS
                if self.motion_steps(prim, np.asarray(local_pts, np.float64)) is not None:
                    self.warn(f"{prim.GetPath()}: a shaped CylinderLight that moves keeps its shaping axis "
                              f"where it is at the frame")
            surface["shaping"] = tuple(float(c) for c in columns)
        if texture is not None:
            # The core reads a texture in place of the constant: scaled by the radiance.
            texture = {**texture, "scale": [*(float(x) for x in radiance), 1.0]}
            surface["textures"] = {"emissiveColor": self.materials.add_texture(texture)}
        row = self.materials.add(surface, two_sided)
        if self.light_links:
            row = self.materials.linked(row, self.light_links.group_of(prim.GetPath()),
                                        self.light_links.link_of(prim.GetPath()))
        chunk = _Chunk(np.asarray(local_pts, np.float64), np.asarray(tris), np.full(len(tris), row, np.uint32),
                       uvs=None if texture is None else np.asarray(uvs, np.float32))
        mats = self.motion_steps(prim, chunk.points)  # area lights move as geometry does
        if mats is not None:
            self.add_moving_chunk(chunk, mats, str(prim.GetPath()))
        else:
            self.emit(chunk.transformed(m), self.chunks, str(prim.GetPath()))

    @reads("RectLight")
    def add_rect_light(self, prim) -> None:
        from pxr import UsdLux

        rect = UsdLux.RectLight(prim)
        w = read_float(rect.GetWidthAttr(), self.time)
        h = read_float(rect.GetHeightAttr(), self.time)
        # Wound so the geometric normal is local -Z, the emitting side.
        local = np.array([[-w / 2, -h / 2, 0], [-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0]])
        texture = self._rect_texture(prim, rect)
        # The image seen from the emitting side, upright: its top-left corner at (+X, +Y)
        # and bottom-right at (-X, -Y) (the schema's orientation); st's t runs up the image.
        st = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
        m = self.world_matrix(prim)
        world = local @ m[:3, :3] + m[3, :3]
        area = float(np.linalg.norm(np.cross(world[1] - world[0], world[3] - world[0])))
        if not (area > 0.0) or not np.isfinite(world).all():
            self.warn(f"{prim.GetPath()}: RectLight has no area; skipped")
            return
        tris = np.array([[0, 1, 2], [0, 2, 3]])
        self._emissive(prim, local, tris, self.light_radiance(prim, area), texture=texture, uvs=st[tris],
                       shaped="normal")

    def _rect_texture(self, prim, rect) -> dict | None:
        """inputs:texture:file as an emissive texture (None without one, or when it is
        missing: then the light keeps its colour, with the sandbox's warning)."""
        import os

        from pxr import Sdf

        attr = rect.GetTextureFileAttr()
        asset = attr.Get(self.time)
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            return None
        layer = authoring_layer(attr)
        return self._texture_from(
            asset=asset, anchor=os.path.dirname(layer.realPath) if layer else None, where=str(prim.GetPath()),
            input_name="emissiveColor", channel="rgb", fallback=[1.0, 1.0, 1.0, 1.0], wrap_s="clamp",
            wrap_t="clamp", scale=[1.0, 1.0, 1.0, 1.0], bias=[0.0, 0.0, 0.0, 0.0], color_space="auto",
            st_primvar=None, transform2d=None)

    @reads("DiskLight")
    def add_disk_light(self, prim) -> None:
        from pxr import UsdLux

        r = read_float(UsdLux.DiskLight(prim).GetRadiusAttr(), self.time)
        m = self.world_matrix(prim)
        # True disk area (not the polygon's): a non-uniform scale stretches it to an ellipse.
        area = math.pi * r * r * float(np.linalg.norm(np.cross(m[0, :3], m[1, :3])))
        if not (area > 0.0) or not math.isfinite(area):
            self.warn(f"{prim.GetPath()}: DiskLight has no area; skipped")
            return
        pts, tris = gprims.disk_light(r)
        self._emissive(prim, pts, tris, self.light_radiance(prim, area), shaped="normal")

    @reads("CylinderLight")
    def add_cylinder_light(self, prim) -> None:
        from pxr import UsdLux

        cyl = UsdLux.CylinderLight(prim)
        r = read_float(cyl.GetRadiusAttr(), self.time)
        length = read_float(cyl.GetLengthAttr(), self.time)
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
        self._emissive(prim, pts, tris, self.light_radiance(prim, area), shaped="axis")

    @reads("SphereLight")
    def add_sphere_light(self, prim) -> None:
        from pxr import UsdLux

        sphere = UsdLux.SphereLight(prim)
        radius = read_float(sphere.GetRadiusAttr(), self.time)
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

    @reads("DistantLight")
    def add_distant_light(self, prim) -> None:
        from pxr import UsdLux

        m = self.world_matrix(prim)
        direction = -m[2, :3]
        direction = direction / np.linalg.norm(direction)
        angle = read_float(UsdLux.DistantLight(prim).GetAngleAttr(), self.time)
        half = math.radians(min(max(angle, 0.0), 180.0)) / 2.0
        # normalize: intensity is the illuminance on a surface facing the light, so
        # radiance = E / (pi sin^2 half). For a delta light (angle 0) the row holds that
        # illuminance directly (documented in docs/scene-translation.md).
        radiance = self.light_radiance(prim, None)
        if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(self.time) and half > 0:
            radiance = radiance / (math.pi * math.sin(half) ** 2)
        radiance = radiance * light_shaping.along_axis_factor(self, prim)
        self.distant_lights.append([*direction, half, *radiance])

    @reads("DomeLight")
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
            layer = authoring_layer(attr)
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


def light_kind_number(name: str) -> int:
    """The core's LightKind number of a kind that can move (SceneData.light_motion_kinds):
    the core lists its kinds (lights/light_kinds.h), this file does not copy them."""
    for number, (kind, moves, *_) in enumerate(_core.light_kinds()):
        if kind == name and moves:
            return number
    raise ValueError(f"the renderer core has no light kind {name!r} that can move")

# The one line a light-less stage gets; Scene rewrites it when default lighting is off.
NO_LIGHT_WARNING = ("the scene has no lights: lit by the default lighting (a white dome of radiance "
                    "0.5 and a key light from above and left of the camera; --no-default-light or "
                    "the job setting default_light=false renders it unlit, i.e. black)")
NO_LIGHT_OFF_WARNING = "the scene has no lights and default lighting is off: it renders black"
DEFAULT_LIGHTING_NAME = "the default lighting (a dome of radiance 0.5 and a key light of illuminance 0.8 pi)"
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
    """Whether any triangle's material may emit: a constant emissiveColor above 0, or an
    emissiveColor texture (whose constant is only its fallback, often 0). A cheap first
    test: usd/emission.py measures what it emits."""
    used = set(np.unique(tri_material).tolist())
    for proto in prototypes:
        used.update(np.unique(proto["triangle_material"]).tolist())
    return any(any(c > 0 for c in rows[m]["values"]["emissiveColor"]) or "emissiveColor" in rows[m]["textures"]
               for m in used if m < len(rows))
