"""UsdVol.Volume prims with OpenVDB fields as grid media (docs/media.md).

A Volume's `density` field (an OpenVDBAsset: a .vdb file inside the bundle and a grid
name) becomes a dense float grid over the bounding box of the grid's active voxels (each
voxel a cube of its value out to the box's faces: media/density_grid.h), with an affine
world -> index map from the VDB's linear transform and the prim's world transform. Its boundary is
the grid's box as a closed mesh of a pure medium interface (the core's binding model: a
medium lives inside a closed mesh). The look:
  - unbound: grey smoke, as usdview shows one: scattering albedo 0.8 grey, density scale 1
    (sigma_s = 0.8 D, sigma_a = 0.2 D per scene unit);
  - a bound material with a MaterialX-style volume (`anisotropic_vdf`: absorption,
    scattering colours, anisotropy) or the common pyro inputs on the material's volume
    shader (density / densityScale, scattering / scatteringColor, absorption /
    absorptionColor, anisotropy / g) reads those.
What is not read (temperature, Cd/color, flame/heat and velocity fields; emission) is
named in one warning per scene. The VDB is read with OpenVDB (Debian libopenvdb-dev,
libtessera_vdb), once per (file, grid) per translation.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .authoring import authoring_layer
from .errors import SceneError

DEFAULT_ALBEDO = 0.8
DEFAULT_DENSITY_SCALE = 1.0
# Field names Houdini and Blender write for what the core does not render yet.
_UNREAD_FIELDS = {"temperature": "temperature", "Cd": "colour (Cd)", "color": "colour", "flame": "flame",
                  "heat": "heat", "vel": "velocity", "v": "velocity", "velocity": "velocity",
                  "fuel": "fuel", "emission": "emission"}
_DENSITY_NAMES = ("density", "density_grid", "smoke")


@dataclass
class VolumeGrid:
    """A translated density field: `density` (nz, ny, nx) float32 and index_to_world, the
    float64 4x4 affine (row vectors, USD's convention) from the grid's index space (voxel
    (i, j, k) spans [i, i+1]...) to world space."""

    density: np.ndarray
    index_to_world: np.ndarray


def _vdb_library():
    """libtessera_vdb (renderer/python/vdb_reader.cpp), loaded once."""
    global _VDB
    if _VDB is None:
        import ctypes
        from pathlib import Path

        from .. import _core  # installed beside it (an editable install keeps the sources elsewhere)

        lib = ctypes.CDLL(str(Path(_core.__file__).parent / "libtessera_vdb.so"))
        lib.tessera_vdb_open.restype = ctypes.c_void_p
        lib.tessera_vdb_open.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_void_p, ctypes.c_void_p,
                                         ctypes.c_char_p, ctypes.c_int]
        lib.tessera_vdb_fill.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.tessera_vdb_free.argtypes = [ctypes.c_void_p]
        _VDB = lib
    return _VDB


_VDB = None


def read_density_grid(path: str, grid_name: str) -> VolumeGrid:
    """The grid `grid_name` of a .vdb file as a dense grid over its active voxels' box."""
    import ctypes

    lib = _vdb_library()
    dims = np.zeros(3, np.int64)
    matrix = np.zeros(16, np.float64)
    err = ctypes.create_string_buffer(1024)
    handle = lib.tessera_vdb_open(os.fsencode(path), grid_name.encode(), dims.ctypes.data, matrix.ctypes.data,
                                  err, len(err))
    if not handle:
        raise SceneError(f"{os.path.basename(path)}: {err.value.decode(errors='replace')}")
    try:
        nx, ny, nz = (int(d) for d in dims)
        density = np.empty((nz, ny, nx), np.float32)
        lib.tessera_vdb_fill(handle, density.ctypes.data)
    finally:
        lib.tessera_vdb_free(handle)
    if not np.isfinite(density).all() or (density < 0).any():
        raise SceneError(f"{os.path.basename(path)}: grid {grid_name!r} has negative or non-finite densities")
    return VolumeGrid(density, matrix.reshape(4, 4))


def _box_chunk_arrays(index_to_world: np.ndarray, dims: tuple[int, int, int]):
    """The grid box's 8 world corners and 12 triangles, wound outward in world space."""
    nx, ny, nz = dims
    corners = np.array([[i & 1 and nx, i & 2 and ny, i & 4 and nz] for i in range(8)], np.float64)
    world = np.c_[corners, np.ones(8)] @ index_to_world
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
    if np.linalg.det(index_to_world[:3, :3]) < 0:  # a mirroring transform turns the winding inside out
        tris = tris[:, ::-1].copy()
    return world[:, :3], tris


def _volume_look(material, time) -> tuple[dict, list[str]]:
    """sigma per unit density and g from a bound material's volume shader; the inputs not
    read by name."""
    from pxr import UsdShade

    look = {"scattering": np.full(3, DEFAULT_ALBEDO), "absorption": np.full(3, 1.0 - DEFAULT_ALBEDO),
            "density": DEFAULT_DENSITY_SCALE, "g": 0.0}
    unread: list[str] = []
    if not material:
        return look, unread
    shaders = []
    for output in material.GetOutputs():
        if "volume" not in output.GetBaseName():
            continue
        for source in output.GetConnectedSources()[0]:
            shaders.append(UsdShade.Shader(source.source.GetPrim()))
    seen = set()
    names = {"density": "density", "densityscale": "density", "density_scale": "density",
             "scattering": "scattering", "scatteringcolor": "scattering", "scattering_color": "scattering",
             "albedo": "scattering", "absorption": "absorption", "absorptioncolor": "absorption",
             "absorption_color": "absorption", "anisotropy": "g", "g": "g"}
    while shaders:
        shader = shaders.pop()
        if not shader or shader.GetPath() in seen:
            continue
        seen.add(shader.GetPath())
        for inp in shader.GetInputs():
            name = inp.GetBaseName()
            sources = inp.GetConnectedSources()[0]
            if sources:
                shaders.extend(UsdShade.Shader(s.source.GetPrim()) for s in sources)
                continue
            key = names.get(name.lower())
            value = inp.Get(time)
            if key is None or value is None:
                if name not in ("vdf", "edf", "file"):
                    unread.append(name)
                continue
            if key in ("scattering", "absorption"):
                v = np.asarray(value, np.float64).reshape(-1)
                look[key] = np.repeat(v, 3)[:3] if v.size == 1 else v[:3]
            else:
                look[key] = float(value)
    return look, unread


class VolumeReader:
    """Mixin for the stage translator: add_volume() per UsdVol.Volume prim."""

    def add_volume(self, prim, m_world: np.ndarray) -> None:
        from pxr import UsdShade, UsdVol

        path = str(prim.GetPath())
        volume = UsdVol.Volume(prim)
        fields = volume.GetFieldPaths()
        density_field = None
        for name, field_path in fields.items():
            field_prim = self.stage.GetPrimAtPath(field_path)
            asset = UsdVol.OpenVDBAsset(field_prim)
            grid_name = (asset.GetFieldNameAttr().Get(self.time) if asset else None) or name
            if density_field is None and (name in _DENSITY_NAMES or grid_name in _DENSITY_NAMES):
                density_field = (name, asset, str(grid_name))
            else:
                self.volume_unread.add(_UNREAD_FIELDS.get(name, _UNREAD_FIELDS.get(str(grid_name), f"{name!r}"))
                                       + " fields")
        if density_field is None:
            self.warn(f"{path}: Volume has no density field (OpenVDBAsset named density); skipped")
            return
        name, asset, grid_name = density_field
        if not asset:
            self.warn(f"{path}: field {name!r} is not an OpenVDBAsset; skipped")
            return
        file_attr = asset.GetFilePathAttr()
        authored = file_attr.Get(self.time)
        if authored is None or not authored.path:
            self.warn(f"{path}: field {name!r} names no file; skipped")
            return
        file = self._volume_file(file_attr, authored, path)
        if file is None:
            self.warn(f"{path}: VDB file {authored.path!r} is missing; skipped")
            return
        key = (file, grid_name)
        grid = self.volume_grids_read.get(key)
        if grid is None:
            grid = read_density_grid(file, grid_name)
            self.volume_grids_read[key] = grid
        material = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        look, unread = _volume_look(material, self.time)
        for n in unread:
            self.volume_unread.add(f"material input {n!r}")
        index_to_world = grid.index_to_world @ m_world
        scale = look["density"]
        coefficients = np.r_[look["absorption"] * scale, look["scattering"] * scale, look["g"]].astype(np.float32)
        if not np.isfinite(coefficients).all() or (coefficients[:6] < 0).any() or abs(coefficients[6]) >= 1:
            raise SceneError(f"{path}: volume material gives sigma_a {coefficients[:3]}, sigma_s "
                             f"{coefficients[3:6]}, g {coefficients[6]}: they must be >= 0 and |g| < 1")
        if np.linalg.det(index_to_world[:3, :3]) == 0:
            self.warn(f"{path}: Volume's transform is singular; skipped")
            return
        self.volumes.append({"path": path, "density": grid.density, "index_to_world": index_to_world,
                             "coefficients": coefficients})


    def _volume_file(self, attr, asset, where: str) -> str | None:
        """The .vdb file an OpenVDBAsset names, inside the bundle (SceneError if it climbs
        out); None when it does not exist."""
        layer = authoring_layer(attr)
        anchor = os.path.dirname(layer.realPath) if layer else None
        if self.bundle is not None:
            found = self.bundle.resolve_texture(asset, anchor, where)
            return None if found is None else str(found)
        resolved = asset.resolvedPath or (os.path.join(anchor, asset.path) if anchor else asset.path)
        return resolved if resolved and os.path.isfile(resolved) else None


def volume_tables(volumes: list[dict], shift: np.ndarray, first_medium: int) -> tuple[list, list]:
    """The core's grid media (density, world_to_index (3, 4), coefficients) with world
    moved by -shift (the camera-relative frame), and per volume its box (world corners,
    triangles, medium index)."""
    grids, boxes = [], []
    for k, v in enumerate(volumes):
        m = v["index_to_world"].copy()
        m[3, :3] -= shift
        inv = np.linalg.inv(m)  # world -> index, row vectors: q = [p, 1] @ inv
        world_to_index = np.ascontiguousarray(inv[:, :3].T, np.float32)  # (3, 4): q = W @ (p, 1)
        grids.append((v["density"], world_to_index, v["coefficients"]))
        nz, ny, nx = v["density"].shape
        corners, tris = _box_chunk_arrays(m, (nx, ny, nz))
        boxes.append((corners, tris, first_medium + k))
    return grids, boxes
