"""UsdPreviewSurface, MaterialX looks and UsdUVTexture -> deduplicated material rows and a
texture table (the MaterialReader part of the translator)."""
from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import numpy as np

from . import media
from .authoring import authoring_layer
from .errors import SceneError


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


class _MaterialTable:
    """Deduplicates material rows: every parameter, texture binding and the two-sidedness."""

    def __init__(self) -> None:
        self.rows: list[dict] = []
        self._index: dict[Any, int] = {}
        self.textures: list[dict] = []
        self._tex_index: dict[Any, int] = {}
        self.has_interiors = False  # some row has an absorbing interior (usd/media.py)

    def add_texture(self, tex: dict) -> int:
        # JSON text as the key: values include lists and the UsdTransform2d dict.
        key = json.dumps(tex, sort_keys=True, default=str)
        if key not in self._tex_index:
            self._tex_index[key] = len(self.textures)
            self.textures.append(tex)
        return self._tex_index[key]

    def add(self, surface: dict, two_sided: bool) -> int:
        preview = bool(surface.get("preview", False))
        shaping = surface.get("shaping")  # a shaped area light's columns (light_shaping)
        # An absorbing interior (sigma_a, usd/media.py) and the side it lies on, or a tint
        # of the transmission at the surface.
        interior, side, tint = surface.get("interior"), surface.get("medium_side"), surface.get("tint")
        self.has_interiors = self.has_interiors or interior is not None
        key = (tuple(sorted((k, v) for k, v in surface["values"].items())),
               tuple(sorted(surface["textures"].items())), bool(two_sided), preview, shaping, interior, side, tint)
        if key not in self._index:
            self._index[key] = len(self.rows)
            self.rows.append({"values": surface["values"], "textures": surface["textures"],
                              "two_sided": bool(two_sided), "preview": preview, "shaping": shaping,
                              "interior": interior, "medium_side": side, "tint": tint,
                              "interior_color": surface.get("interior_color")})
        return self._index[key]

    def linked(self, row: int, group: int, light: int = -1) -> int:
        """Row `row` for surfaces of link group `group` (light_links.py), or for the area
        light of link `light`: the row itself for group 0 and no link."""
        if group == 0 and light < 0:
            return row
        key = ("linked", row, group, light)
        if key not in self._index:
            self._index[key] = len(self.rows)
            self.rows.append({**self.rows[row], "link_group": group, "light_link": light})
        return self._index[key]


class MaterialReader:
    """Resolves bindings into material rows and textures."""

    # -- materials ------------------------------------------------------------------
    def material_row(self, bind_prim, geom_prim, double_sided: bool) -> int:
        from pxr import UsdGeom, UsdShade

        material, _ = UsdShade.MaterialBindingAPI(bind_prim).ComputeBoundMaterial()
        display = None
        color = UsdGeom.Gprim(geom_prim).GetDisplayColorAttr().Get(self.time) if UsdGeom.Gprim(geom_prim) else None
        if color is not None:
            try:
                rows = np.asarray(color, np.float64).reshape(-1, 3)
            except (TypeError, ValueError):  # composes from `color3f[] primvars:displayColor = </P>`
                rows = None
                self._count_note("primvars:displayColor values that are not colours are ignored")
            if rows is not None and len(rows) > 0:
                display = tuple(float(x) for x in rows[0])
        target = None if material else self._dangling_binding(bind_prim)
        if target is not None:
            # Bound to a path where no Material composed: a look in a .mtlx layer (usd-core
            # has no usdMtlx plugin), read with the MaterialX reader, or named as grey.
            key = (str(target), display)
            if key not in self._surface_cache:
                self._surface_cache[key] = self._mtlx_layer_surface(bind_prim.GetStage(), target, display)
            surface = self._surface_cache[key]
        elif not material:
            surface = self._plain_surface(display, str(geom_prim.GetPath()))
        else:
            mprim = material.GetPrim()
            # Materials under instances are instance proxies: one read per prototype material.
            mpath = mprim.GetPrimInPrototype().GetPath() if mprim.IsInstanceProxy() else mprim.GetPath()
            key = (str(mpath), display)
            if key not in self._surface_cache:
                self._surface_cache[key] = self._read_preview_surface(material, display)
            surface = self._surface_cache[key]
        row = self.materials.add(surface, double_sided)
        return self.materials.linked(row, self.light_links.group_of(geom_prim.GetPath())) if self.light_links else row

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
        out = {"values": values, "textures": {k: self.materials.add_texture(t) for k, t in textures.items()},
               "preview": True}
        tinted = mtlx.transmission_tint(node, self._count_note)
        if tinted is not None:
            color, depth = tinted
            if any(not 0.0 < c <= 1.0 for c in color):
                self._count_note(f"MaterialX transmission_color outside (0, 1] is clamped to it ({path})")
                color = tuple(min(max(c, media.MIN_TRANSMISSION_COLOR), 1.0) for c in color)
            if depth > 0.0:
                # Beer-Lambert inside: bound to the mesh when it is closed (bind_interiors).
                out.update(interior=media.absorption(color, depth), interior_color=color, medium_side="inside")
            else:
                out.update(self._surface_tint(values, color, path))
        return out

    def _surface_tint(self, values, color, path) -> dict:
        """The transmission colour applied at the surface, on each crossing (standard_surface's
        rule for transmission_depth 0). Only a fully transmissive surface carries it."""
        if values["opacity"][0] > 0.0:
            self._count_note("MaterialX transmission_color on partly transmissive surfaces (transmission "
                             f"below 1) is not applied: only transmission 1 is tinted ({path})")
            return {}
        return {"tint": tuple(float(c) for c in color)}

    def bind_interiors(self, chunk, path: str):
        """The chunk with its absorbing-glass materials bound to their inside: the rows of a
        closed mesh's faces keep their medium (on the side opposite the normals, or on
        theirs for a mesh wound inward); faces that close no volume tint their surface
        instead, with one warning."""
        if not self.materials.has_interiors:  # the common case: no per-chunk work
            return chunk
        rows = self.materials.rows
        glass = [int(r) for r in np.unique(chunk.material) if rows[int(r)].get("interior") is not None]
        if not glass:
            return chunk
        material = chunk.material.copy()
        for r in glass:
            faces = chunk.material == r
            row = rows[r]
            orientation = media.closed_orientation(chunk.points, chunk.tris[faces])
            surface = {"values": row["values"], "textures": row["textures"], "preview": row["preview"],
                       "shaping": row["shaping"]}
            if orientation == 0:
                self._count_note("transmissive MaterialX surfaces with a transmission_depth on meshes whose faces "
                                 "close no volume (open or inconsistently wound) have no inside to absorb in: "
                                 "their transmission_color tints the surface instead")
                surface.update(self._surface_tint(row["values"], row["interior_color"], path))
            elif orientation < 0:
                surface.update(interior=row["interior"], interior_color=row["interior_color"],
                               medium_side="outside")
            else:
                continue
            material[faces] = self.materials.add(surface, row["two_sided"])
        return dataclasses.replace(chunk, material=material)

    @staticmethod
    def _dangling_binding(bind_prim):
        """The path a prim's direct binding (its own or its nearest bound ancestor's) names
        when no Material stands there, else None."""
        from pxr import UsdShade

        prim = bind_prim
        while prim and not prim.IsPseudoRoot():
            rel = UsdShade.MaterialBindingAPI(prim).GetDirectBindingRel()
            targets = rel.GetForwardedTargets() if rel else []
            if targets:
                bound = prim.GetStage().GetPrimAtPath(targets[0])
                return None if bound and bound.IsA(UsdShade.Material) else targets[0]
            prim = prim.GetParent()
        return None

    def _mtlx_layer_surface(self, stage, target, display) -> dict:
        """The surface of a material bound at `target` that lives in a .mtlx document
        referenced or payloaded by one of its ancestors (the document's material named
        as the path's last element), or sublayered; grey, named, when there is none."""
        import os

        from . import mtlx

        where = str(target)
        reason = "no material at the bound path"
        arcs = []  # (layer, asset path, material name)
        path = target
        while not path.isEmpty and path != path.absoluteRootPath:
            prim = stage.GetPrimAtPath(path)
            if prim:
                for spec in prim.GetPrimStack():
                    for arc in list(spec.referenceList.GetAddedOrExplicitItems()) + \
                            list(spec.payloadList.GetAddedOrExplicitItems()):
                        # On the bound prim itself (typeless: its arc did not compose), the
                        # arc names the material; above it, the bound path's last element.
                        own = path == target and not arc.primPath.isEmpty
                        arcs.append((spec.layer, arc.assetPath, arc.primPath.name if own else target.name))
            path = path.GetParentPath()
        for layer in stage.GetLayerStack(includeSessionLayers=False):
            arcs += [(layer, sub, target.name) for sub in layer.subLayerPaths]
        for layer, asset, name in arcs:
            if not asset.lower().endswith(".mtlx"):
                continue
            anchor = os.path.dirname(layer.realPath)
            file = self.bundle.check_asset(asset, anchor, what=f"{where}: {asset}") if self.bundle is not None \
                else os.path.join(anchor, asset)
            if not os.path.isfile(file):
                reason = f"{asset} missing"
                continue
            node, why = mtlx.read_mtlx_material(str(file), name, f"{where}: {asset}", exact=True)
            if node is not None and node.category in mtlx.SURFACE_CATEGORIES:
                return self._mtlx_surface(node, where)
            reason = why or (f"MaterialX {node.category}" if node is not None else reason)
        self.grey_materials[where] = reason
        return self._plain_surface(display, where)

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
                spec_layer = authoring_layer(a)
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


def _input_value(shader, name, time):
    inp = shader.GetInput(name)
    if not inp:
        return None
    for attr in inp.GetValueProducingAttributes():
        if attr.GetName().startswith("outputs:"):
            return None
        return attr.Get(time)
    return None


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
