"""MaterialX looks -> UsdPreviewSurface inputs (Tessera's BSDF).

usd-core from PyPI has no usdMtlx file format, so a look authored in MaterialX reaches us
in one of two ways, both read here with the same mapping:

- inline: UsdShade Shader prims whose info:id is a MaterialX node definition
  (`ND_standard_surface_surfaceshader`, `ND_image_color3`, ...) behind a material's
  `outputs:mtlx:surface` (Houdini, Omniverse, the usd-wg intent-vfx assets);
- a `.mtlx` document a Material prim references (`@look.mtlx@</MaterialX/Materials/M>`,
  the usdMtlx convention), read with the MaterialX library (the `materialx` package) with
  XIncludes off, so it opens no file the bundle sandbox did not check.

Surfaces mapped: standard_surface, open_pbr_surface and UsdPreviewSurface (the MaterialX
node). Inputs may be constants or image / tiledimage / UsdUVTexture nodes (through node
graphs, with a normalmap node for normals, and texcoord / geompropvalue /
UsdPrimvarReader naming the UV set), and affine math on at most one image -- constant,
multiply, divide (by a constant), add, subtract, mix (by a constant weight), convert,
dot -- folded into that texture's scale and bias; anything else (two images combined,
noise, ramps, ...) falls back to its default, noted.
Defaults come from the MaterialX standard library's node definitions.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .authoring import authoring_layer

# The UsdPreviewSurface input each shading model's inputs fill: (preview input, MaterialX
# input, the constant weight multiplying it or None).
_MAPPINGS = {
    "standard_surface": [
        ("diffuseColor", "base_color", "base"), ("metallic", "metalness", None),
        ("roughness", "specular_roughness", None), ("ior", "specular_IOR", None),
        ("clearcoat", "coat", None), ("clearcoatRoughness", "coat_roughness", None),
        ("emissiveColor", "emission_color", "emission"), ("opacity", "opacity", None),
        ("normal", "normal", None)],
    "open_pbr_surface": [
        ("diffuseColor", "base_color", "base_weight"), ("metallic", "base_metalness", None),
        ("roughness", "specular_roughness", None), ("ior", "specular_ior", None),
        ("clearcoat", "coat_weight", None), ("clearcoatRoughness", "coat_roughness", None),
        ("emissiveColor", "emission_color", "emission_luminance"), ("opacity", "geometry_opacity", None),
        ("normal", "geometry_normal", None)],
    "UsdPreviewSurface": [(n, n, None) for n in (
        "diffuseColor", "emissiveColor", "specularColor", "metallic", "roughness", "ior", "clearcoat",
        "clearcoatRoughness", "opacity", "opacityThreshold", "useSpecularWorkflow", "normal")],
}
# The input whose weight makes the surface glass (refraction asked for by the author).
_TRANSMISSION = {"standard_surface": "transmission", "open_pbr_surface": "transmission_weight"}
SURFACE_CATEGORIES = tuple(_MAPPINGS)
_IMAGE_CATEGORIES = ("image", "tiledimage", "UsdUVTexture")
_ADDRESS = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}


def category_of(ident: str | None) -> str | None:
    """`ND_standard_surface_surfaceshader` -> `standard_surface`; `ND_image_color3` ->
    `image`; None when not a MaterialX node definition name."""
    if not ident or not ident.startswith("ND_"):
        return None
    return ident[3:].rsplit("_", 1)[0]


@functools.lru_cache(maxsize=1)
def _library():
    import MaterialX as mx

    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def _default(category: str, node_type: str, name: str):
    """An input's default from the standard library's node definition, as a tuple, or None."""
    nodedef = _library().getNodeDef(f"ND_{category}_{node_type}")
    inp = nodedef.getActiveInput(name) if nodedef is not None else None
    if inp is None or not inp.hasValueString():
        return None
    return _as_tuple(inp.getValue())


def _as_tuple(value) -> tuple | None:
    if value is None:
        return None
    if isinstance(value, str):
        return None
    if isinstance(value, (bool, int, float)):
        return (float(value),)
    try:
        if hasattr(value, "asTuple"):
            return tuple(float(x) for x in value.asTuple())
        return tuple(float(x) for x in value)
    except (TypeError, ValueError):
        return None


# -- node adapters: one interface over UsdShade shaders and MaterialX nodes ------------------
class UsdNode:
    """A UsdShade Shader prim that is a MaterialX node."""

    def __init__(self, shader, time):
        self.shader, self.time = shader, time
        self.ident = shader.GetIdAttr().Get() or ""
        self.category = category_of(self.ident) or ""
        self.type = self.ident.rsplit("_", 1)[-1] if self.ident.startswith("ND_") else ""
        self.where = str(shader.GetPath())

    def _attrs(self, name):
        inp = self.shader.GetInput(name)
        return inp.GetValueProducingAttributes() if inp else []

    def value(self, name):
        for attr in self._attrs(name):
            if attr.GetName().startswith("outputs:"):
                return None
            return attr.Get(self.time)
        return None

    def source(self, name):
        from pxr import UsdShade

        for attr in self._attrs(name):
            if attr.GetName().startswith("outputs:"):
                return UsdNode(UsdShade.Shader(attr.GetPrim()), self.time), attr.GetName().split(":", 1)[1]
        return None

    def file(self, name):
        """(Sdf.AssetPath, authoring layer directory, colour space) of a filename input."""
        for attr in self._attrs(name):
            layer = authoring_layer(attr)
            space = attr.GetColorSpace() if attr.HasColorSpace() else ""
            return attr.Get(self.time), (os.path.dirname(layer.realPath) if layer else None), space
        return None, None, ""


class MxNode:
    """A node of a MaterialX document read from a .mtlx file in the bundle."""

    def __init__(self, node, doc_dir: str, doc):
        self.node, self.doc_dir = node, doc_dir
        self.doc = doc  # elements keep no reference to their document: hold it here
        self.category = node.getCategory()
        self.type = node.getType()
        self.ident = node.getNodeDefString() or f"ND_{self.category}_{self.type}"
        self.where = f"{os.path.basename(doc.getSourceUri() or 'mtlx')}:{node.getNamePath()}"

    def value(self, name):
        inp = self.node.getInput(name)
        if inp is None or inp.getConnectedOutput() is not None or inp.getConnectedNode() is not None:
            return None
        iface = inp.getInterfaceInput() if hasattr(inp, "getInterfaceInput") else None
        src = iface if iface is not None else inp
        return src.getValue() if src.hasValueString() else None

    def source(self, name):
        inp = self.node.getInput(name)
        if inp is None:
            return None
        out = inp.getConnectedOutput()
        node = out.getConnectedNode() if out is not None else inp.getConnectedNode()
        if node is None:
            return None
        return MxNode(node, self.doc_dir, self.doc), (out.getName() if out is not None else "out")

    def file(self, name):
        inp = self.node.getInput(name)
        if inp is None:
            return None, None, ""
        return inp.getResolvedValueString(), self.doc_dir, inp.getActiveColorSpace() or ""


def read_mtlx_material(path: str, material_name: str | None, where: str, exact: bool = False):
    """The surface shader node (MxNode) of a material in a .mtlx file, or (None, reason).
    Without `exact`, a document of one material gives it whatever its name."""
    import MaterialX as mx

    doc = mx.createDocument()
    opts = mx.XmlReadOptions()
    opts.readXIncludeFunction = None  # includes could name files the sandbox never saw
    try:
        with open(path, encoding="utf-8") as f:
            mx.readFromXmlString(doc, f.read(), mx.FileSearchPath(), opts)
    except (OSError, UnicodeDecodeError, mx.Exception) as exc:
        return None, f"cannot read {os.path.basename(path)} ({exc})"
    doc.setSourceUri(os.path.basename(path))
    materials = doc.getMaterialNodes()
    chosen = [m for m in materials if m.getName() == material_name] or \
        (materials if len(materials) == 1 and not exact else [])
    if not chosen:
        return None, f"no material {material_name!r} in {os.path.basename(path)}"
    shaders = mx.getShaderNodes(chosen[0])
    if not shaders:
        return None, f"material {chosen[0].getName()!r} in {os.path.basename(path)} has no surface shader"
    return MxNode(shaders[0], os.path.dirname(path), doc), None


# -- the mapping ------------------------------------------------------------------------------
def surface(node, defaults: dict, make_texture: Callable[..., dict | None], note: Callable[[str], None]):
    """(values, textures, presence) for a MaterialX surface node: `values` keyed by
    UsdPreviewSurface input (tuples; missing ones keep `defaults`), `textures` keyed by
    input with texture descriptions from `make_texture`, and whether the surface's opacity
    is presence (MaterialX's geometry opacity is coverage; transmission is the glass the
    author asks for)."""
    values = dict(defaults)
    textures: dict[str, dict] = {}
    for preview, name, weight_name in _MAPPINGS[node.category]:
        weight = 1.0
        if weight_name is not None:
            w = _constant(node, weight_name, note)
            weight = w[0] if w else 1.0
        width = len(defaults.get(preview, (0.0, 0.0, 1.0) if preview == "normal" else (0.0,)))
        value, tex = _input(node, name, preview, width, make_texture, note)
        if value is not None:
            values[preview] = tuple(v * weight for v in value) if weight != 1.0 else value
        if tex is not None:
            if weight != 1.0:
                tex["scale"] = [s * weight for s in tex["scale"][:3]] + [tex["scale"][3]]
                tex["fallback"] = [f * weight for f in tex["fallback"][:3]] + [tex["fallback"][3]]
            textures[preview] = tex
    presence = False
    if node.category in _TRANSMISSION:
        t = _constant(node, _TRANSMISSION[node.category], note)
        if t and t[0] > 0.0:
            values["opacity"] = (1.0 - min(t[0], 1.0),)  # glass, refracting with the ior
        elif values["opacity"][0] < 1.0 or "opacity" in textures:
            presence = True
    elif node.category == "UsdPreviewSurface":
        presence = None  # the UsdPreviewSurface rule decides
    return values, textures, presence


# Each model's transmission colour and depth (docs/media.md, "Absorbing glass").
_TRANSMISSION_TINT = {"standard_surface": ("transmission_color", "transmission_depth", "transmission_scatter"),
                      "open_pbr_surface": ("transmission_color", "transmission_depth", "transmission_scatter")}


def transmission_tint(node, note) -> tuple[tuple[float, float, float], float] | None:
    """(transmission colour, transmission depth) of a surface that transmits (weight > 0)
    with a colour other than white, else None. Both models mean the same: with depth d > 0
    the colour is what light keeps after travelling d inside (Beer-Lambert, the volume's
    absorption); with d = 0 the colour tints the refraction at the surface."""
    if node.category not in _TRANSMISSION_TINT:
        return None
    weight = _constant(node, _TRANSMISSION[node.category], note)
    if not weight or weight[0] <= 0.0:
        return None
    color_name, depth_name, scatter_name = _TRANSMISSION_TINT[node.category]
    color = _fit(_constant(node, color_name, note), 3) or (1.0, 1.0, 1.0)
    depth = _constant(node, depth_name, note) or (0.0,)
    scatter = _fit(_constant(node, scatter_name, note), 3) or (0.0, 0.0, 0.0)
    if any(c > 0.0 for c in scatter):
        note(f"MaterialX {scatter_name} (scattering inside transmissive surfaces) is not read: the interior "
             f"only absorbs ({node.ident})")
    if all(c == 1.0 for c in color):
        return None
    return tuple(float(c) for c in color), float(depth[0])


def _constant(node, name, note):
    value = node.value(name)
    if value is None and node.source(name) is not None:
        note(f"textured MaterialX weights are not evaluated; their default is used ({node.ident}.{name})")
    if value is None:
        value = _default(node.category, node.type, name)
    return _as_tuple(value) if not isinstance(value, tuple) else value


def _input(node, name, preview, width, make_texture, note):
    """(value or None, texture or None) of one input."""
    src = node.source(name)
    if src is None:
        value = node.value(name)
        value = _as_tuple(value) if value is not None else _default(node.category, node.type, name)
        return _fit(value, width), None
    inner, output = src
    scale, bias = [1.0] * 4, [0.0] * 4
    if inner.category == "normalmap":  # tangent-space map: in * 2 - 1 (the node's own decode)
        nested = inner.source("in")
        if nested is None:
            return None, None
        inner, output = nested
        scale, bias = [2.0, 2.0, 2.0, 1.0], [-1.0, -1.0, -1.0, 0.0]
    affine = None
    if inner.category in _AFFINE_CATEGORIES:
        # Math on one image and constants folds into the texture's scale and bias.
        affine = _affine(inner, note)
        if affine is None:
            return None, None
        if affine.image is None:
            return _fit(tuple(affine.bias[:max(width, 1)]), width), None
        inner, scale, bias = affine.image, list(affine.scale), list(affine.bias)
    if inner.category not in _IMAGE_CATEGORIES:
        note(f"MaterialX nodes other than image, tiledimage, normalmap, constant and affine math "
             f"(multiply, divide, add, subtract, mix, convert, dot) are not evaluated; their inputs use "
             f"the default ({inner.ident})")
        return None, None
    tex = _image(inner, preview, width, scale, bias, make_texture, note)
    if tex is not None and affine is not None:
        # A missing image gives its fallback through the same arithmetic.
        tex["fallback"] = [f * a + b for f, a, b in zip(tex["fallback"], affine.scale, affine.bias)]
    fallback = tuple(tex["fallback"][:width]) if tex else None
    return (_fit(fallback, width) if fallback else None), tex


@dataclass
class _Affine:
    """texel x scale + bias per channel (r, g, b, a) of one image node, or the constant
    `bias` when `image` is None."""

    image: Any
    scale: np.ndarray
    bias: np.ndarray


_AFFINE_CATEGORIES = ("constant", "multiply", "divide", "add", "subtract", "mix", "convert", "dot")


def _affine(node, note, depth: int = 0) -> _Affine | None:
    """A node graph of constants, affine math and at most one image as an _Affine; None
    (with a note) for anything else: two images, a textured divisor or mix weight, other
    nodes (noise, ramps, ...) or a graph deeper than 64 nodes."""
    cat = node.category
    if cat in _IMAGE_CATEGORIES:
        return _Affine(node, np.ones(4), np.zeros(4))
    if cat not in _AFFINE_CATEGORIES or depth > 64:
        note(f"MaterialX nodes other than image, tiledimage, normalmap, constant and affine math "
             f"(multiply, divide, add, subtract, mix, convert, dot) are not evaluated; their inputs use "
             f"the default ({node.ident})")
        return None

    def operand(name) -> _Affine | None:
        src = node.source(name)
        if src is not None:
            return _affine(src[0], note, depth + 1)
        value = node.value(name)
        value = _as_tuple(value) if value is not None else _default(cat, node.type, name)
        if not value:
            return None
        v = np.array(value[:4] if len(value) > 1 else value * 4, np.float64)
        return _Affine(None, np.zeros(4), np.concatenate([v, np.zeros(4 - len(v))]))

    def one_image(a: _Affine, b: _Affine):
        if a.image is not None and b.image is not None:
            note(f"MaterialX math combining two images is not evaluated; the input uses the default "
                 f"({node.ident})")
            return False, None
        return True, a.image if a.image is not None else b.image

    if cat in ("constant", "convert", "dot"):
        return operand("value" if cat == "constant" else "in")
    if cat == "mix":
        fg, bg, m = operand("fg"), operand("bg"), operand("mix")
        if fg is None or bg is None or m is None:
            return None
        if m.image is not None:
            note(f"MaterialX mix weights from images are not evaluated; the input uses the default ({node.ident})")
            return None
        ok, image = one_image(fg, bg)
        w = m.bias[0]
        return _Affine(image, fg.scale * w + bg.scale * (1 - w), fg.bias * w + bg.bias * (1 - w)) if ok else None
    a, b = operand("in1"), operand("in2")
    if a is None or b is None:
        return None
    ok, image = one_image(a, b)
    if not ok:
        return None
    if cat == "add":
        return _Affine(image, a.scale + b.scale, a.bias + b.bias)
    if cat == "subtract":
        return _Affine(image, a.scale - b.scale, a.bias - b.bias)
    if cat == "multiply":
        if a.image is None:
            a, b = b, a  # the image (if any) first; b is a constant
        return _Affine(image, a.scale * b.bias, a.bias * b.bias)
    # divide: by a constant with no zero channel among r, g, b.
    if b.image is not None or not np.all(b.bias[:3] != 0):
        note(f"MaterialX divisions by an image or by zero are not evaluated; the input uses the default "
             f"({node.ident})")
        return None
    d = np.where(b.bias != 0, b.bias, 1.0)
    return _Affine(image, a.scale / d, a.bias / d)


def _image(node, preview, width, scale, bias, make_texture, note):
    cat = node.category
    file_input = "file"
    asset, anchor, space = node.file(file_input)
    default = node.value("fallback" if cat == "UsdUVTexture" else "default")
    default = _as_tuple(default) or _default(cat, node.type, "fallback" if cat == "UsdUVTexture" else "default") \
        or (0.0,)
    fallback4 = list(default[:4]) + [0.0] * (4 - len(default[:4]))
    if len(default) == 1:
        fallback4 = [default[0]] * 3 + [1.0]
    if cat == "UsdUVTexture":
        wrap_s, wrap_t = str(node.value("wrapS") or "useMetadata"), str(node.value("wrapT") or "useMetadata")
    else:
        wrap_s = _ADDRESS.get(str(node.value("uaddressmode") or "periodic"), "repeat")
        wrap_t = _ADDRESS.get(str(node.value("vaddressmode") or "periodic"), "repeat")
    channel = "rgb" if width == 3 else "r"
    uv = _uv_set(node, note)
    if cat == "tiledimage":
        tiling = _as_tuple(node.value("uvtiling")) or (1.0, 1.0)
        transform = {"scale": list(tiling[:2]), "rotation": 0.0, "translation": [0.0, 0.0]}
    else:
        transform = None
    space = str(space or "")
    color_space = "sRGB" if space.lower().startswith("srgb") else ("raw" if space else "auto")
    return make_texture(asset=asset, anchor=anchor, where=node.where, input_name=preview, channel=channel,
                        fallback=fallback4, wrap_s=wrap_s, wrap_t=wrap_t, scale=list(scale), bias=list(bias),
                        color_space=color_space, st_primvar=uv, transform2d=transform)


def _uv_set(node, note) -> str | None:
    """The UV set an image node reads: texcoord index 0 is the mesh's default set."""
    src = node.source("st" if node.category == "UsdUVTexture" else "texcoord")
    if src is None:
        return None
    reader, _ = src
    if reader.category == "geompropvalue":
        name = reader.value("geomprop")
    elif reader.category == "UsdPrimvarReader":
        name = reader.value("varname")
    elif reader.category == "texcoord":
        index = reader.value("index")
        if index:
            note("MaterialX texcoord indices above 0 use the mesh's default UV set")
        return None
    else:
        note(f"MaterialX texture coordinates from {reader.ident} are not evaluated; the default UV set is used")
        return None
    name = str(name) if name else None
    return name[len("primvars:"):] if name and name.startswith("primvars:") else name


def _fit(value: Any, width: int):
    if value is None:
        return None
    value = tuple(value)
    if len(value) == width:
        return value
    if width == 1:
        return (sum(value) / len(value),)  # e.g. standard_surface's colour opacity
    return (value[0],) * width if len(value) == 1 else tuple(value[:width])
