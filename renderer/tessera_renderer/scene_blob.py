"""Translate once: a translated scene as one versioned binary blob.

    blob = translate_to_blob("bundle.zip")        # sandbox + USD -> bytes (once per scene)
    scene = scene_from_blob(blob)                 # bytes -> Scene, no USD involved

Layout (little-endian):

    8 bytes   magic b"TSSCENE\\0"
    4 bytes   uint32 format version (BLOB_VERSION)
    4 bytes   uint32 header length H
    H bytes   JSON header: scene metadata, array table {name: dtype, shape, offset},
              embedded file table {name: offset, size}
    ...       padding to 64 bytes, then every array's raw bytes (each 64-byte aligned),
              then the bytes of every texture file the scene uses

Arrays come back as zero-copy views of the blob. Texture files travel inside the blob
(a worker that fetches it may not have the bundle) and are written to a private
directory that lives as long as the Scene. Cache keys should include BLOB_VERSION and
TRANSLATOR_VERSION so an upgrade never reads an old blob as new.
"""
from __future__ import annotations

import dataclasses
import math

import json
import os
import shutil
import struct
import tempfile
import weakref
from pathlib import Path

import numpy as np

from .usd import CameraDesc, SceneData, SceneError

MAGIC = b"TSSCENE\0"
BLOB_VERSION = 1
# Bumped whenever translation output changes for the same input.
# 2: camera lens and clipping range; 3: sRGB only for 8-bit colour images on colour
# inputs, NaN st replaced, and instancing "auto" (Embree instances) by default;
# 4: coordinates relative to the camera (SceneData.world_offset); 5: default lighting for
# light-less stages (SceneData.default_lights), UV sets by name, nested packages, tight
# three-quarter default camera, partial opacity as presence (opacity_threshold -1),
# UsdSkel skinning, MaterialX looks; 6: subdivision surfaces refined onto their limit
# surface (OpenSubdiv, level 2) instead of their cages; shaped point lights (ShapingAPI
# cones, focus, IES) with 6 + 192 columns; BasisCurves as triangle tubes; 7: orthographic
# cameras and aperture offsets (CameraDesc.projection, *_aperture_offset); 8: transform
# motion over the camera's shutter (moving instances, motion_* arrays), and the stage's
# startTimeCode as the render time when no frame is given; 9: deforming meshes (a
# prototype's motion_positions), moving sphere, point, distant and dome lights
# (light_motion_*), still-time values that are not numbers refused, RectLight textures,
# shaped Rect and Disk lights (material_shaping); 10: IES tables by vertical and horizontal
# angle (SceneData.ies_tables; shaping columns 14: the table index and the +X axis),
# shaped Cylinder lights (about their -Z) and Distant lights (along their direction),
# still curves of the world as Embree round curves (SceneData.curves); 11: light-lessness
# by UsdLux lights and the measured power of material emission (usd/emission.py), and
# SceneData.brightest_light; 12: MaterialX transmission colour and depth (absorbing
# interiors of closed meshes, SceneData.media and material_media; a tint at depth 0); 13:
# UsdLux light and shadow links (SceneData.light_links), NurbsPatch trim curves cut out;
# 14: PortalLights (SceneData.light_rows["portal"]); 15: UsdVol.Volume density fields as
# grid media in boxes of pure medium interfaces (SceneData.grid_media,
# material_interface_only).
TRANSLATOR_VERSION = 15
_ALIGN = 64
_LIGHT_MOTION_FIELDS = ("light_motion_kinds", "light_motion_indices", "light_motion_time_steps",
                        "light_motion_transforms")
_PROTO_FIELDS = ("positions", "indices", "triangle_material", "shading_normals", "uvs", "motion_positions")


def format_tag() -> str:
    """Names blob format and translator together: the farm keys translated scenes by it so
    an upgraded worker never reads a stale blob."""
    return f"v{BLOB_VERSION}.{TRANSLATOR_VERSION}"


def translate_to_blob(path: str | Path, frame: float | None = None, *, root: str | Path | None = None,
                      instancing: str = "auto", subdivision_level: int | None = None,
                      camera: str | None = None, shutter: tuple[float, float] | None = None,
                      variants=(), dicing=None) -> bytes:
    """Sandboxes, pre-flights and translates a bundle; returns the blob. SceneError for
    bad input. A light-less stage's default lighting travels in the blob unapplied:
    scene_from_blob(blob, default_light=...) decides. `frame`, `subdivision_level`,
    `camera`, `shutter`, `variants` and `dicing` as in load_scene."""
    from .usd import translate_stage
    from .usd.subdivision import DEFAULT_LEVEL

    data = translate_stage(str(path), frame, root=None if root is None else str(root),
                           instancing=instancing,
                           subdivision_level=DEFAULT_LEVEL if subdivision_level is None else subdivision_level,
                           camera=camera, shutter=shutter, variants=tuple(variants),
                           dicing=dicing if subdivision_level is None else None)
    try:
        return scene_data_to_blob(data)
    finally:
        bundle = getattr(data, "_bundle", None)
        if bundle is not None:
            bundle.cleanup()


def blob_size(data: SceneData) -> int:
    """The size of scene_data_to_blob(data) without building it, but for its JSON header
    (a few KB): what the farm will keep of this scene in Redis, for the pre-flight's limit."""
    arrays, files = _blob_arrays(data), _blob_files(data)[0]
    size = 0
    for a in arrays.values():
        size = _aligned(size + a.nbytes)
    for _, src in files:
        size = _aligned(size + os.path.getsize(src))
    return size


def _blob_arrays(data: SceneData) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {
        "positions": data.positions, "indices": data.indices, "triangle_material": data.triangle_material,
        "albedo": data.albedo, "emission": data.emission, "two_sided_emission": data.two_sided_emission,
        "sphere_lights": data.sphere_lights, "distant_lights": data.distant_lights,
        "point_lights": data.point_lights, "instances": data.instances,
        "instance_transforms": data.instance_transforms,
        "motion_instances": data.motion_instances, "motion_time_steps": data.motion_time_steps,
        "motion_transforms": data.motion_transforms,
        **{k: getattr(data, k) for k in _LIGHT_MOTION_FIELDS},
    }
    if getattr(data, "material_shaping", None) is not None:
        arrays["material_shaping"] = data.material_shaping
    if getattr(data, "ies_tables", None) is not None:
        arrays["ies_tables"] = data.ies_tables
    for key in ("media", "material_media"):
        if getattr(data, key, None) is not None:
            arrays[key] = getattr(data, key)
    for key, value in (getattr(data, "curves", None) or {}).items():
        arrays[f"curves.{key}"] = value
    for key, value in (getattr(data, "light_links", None) or {}).items():
        arrays[f"light_links.{key}"] = value
    for kind, rows in (getattr(data, "light_rows", None) or {}).items():
        arrays[f"light_rows.{kind}"] = np.asarray(rows, np.float32)
    for key, value in data.material_params.items():
        arrays[f"material_params.{key}"] = value
    if data.shading_normals is not None:
        arrays["shading_normals"] = data.shading_normals
    if data.uvs is not None:
        arrays["uvs"] = data.uvs
    for i, (density, world_to_index, coefficients) in enumerate(getattr(data, "grid_media", None) or []):
        arrays[f"grid_media.{i}.density"] = density
        arrays[f"grid_media.{i}.world_to_index"] = world_to_index
        arrays[f"grid_media.{i}.coefficients"] = coefficients
    for key in ("material_interface_only",):
        if getattr(data, key, None) is not None:
            arrays[key] = getattr(data, key)
    for i, proto in enumerate(data.prototypes):
        for f in _PROTO_FIELDS:
            if proto.get(f) is not None:
                arrays[f"prototypes.{i}.{f}"] = proto[f]
    return arrays


def _blob_files(data: SceneData) -> tuple[list[tuple[str, str]], list[dict], dict | None]:
    """The texture files the blob carries (blob name, source path), and the textures and
    dome light with their files renamed to those names."""
    # Texture files, each once, named by their index in the blob.
    files: list[tuple[str, str]] = []   # (blob name, source path)
    by_source: dict[str, str] = {}
    textures = []
    for k, tex in enumerate(data.textures):
        tex = dict(tex)
        src = tex["file"]
        if "<UDIM>" in src:
            # Tiles of one UDIM set share a directory so the pattern still names them.
            tiles = _udim_files(src)
            for s in tiles:
                files.append((f"u{k}/{os.path.basename(s)}", s))
            tex["file"] = f"u{k}/{os.path.basename(src)}"
            tex["udim_files"] = [f"u{k}/{os.path.basename(s)}" for s in tiles]
        else:
            if src not in by_source:
                by_source[src] = f"f{len(by_source)}/{os.path.basename(src)}"
                files.append((by_source[src], src))
            tex["file"] = by_source[src]
        textures.append(tex)
    dome = dict(data.dome_light) if data.dome_light else None
    if dome and dome.get("texture"):
        src = dome["texture"]
        if src not in by_source:
            by_source[src] = f"f{len(by_source)}/{os.path.basename(src)}"
            files.append((by_source[src], src))
        dome["texture"] = by_source[src]
    return files, textures, dome


def scene_data_to_blob(data: SceneData) -> bytes:
    arrays = _blob_arrays(data)
    files, textures, dome = _blob_files(data)
    c = data.camera
    meta = {
        "camera": {k: (v if math.isfinite(v) else None) if isinstance(v, float) else v
                   for k, v in dataclasses.asdict(c).items()},
        "resolution": list(data.resolution), "resolution_from_stage": data.resolution_from_stage,
        "warnings": data.warnings, "textures": textures,
        "material_textures": [[m, name, t] for (m, name), t in data.material_textures.items()],
        "dome_light": dome, "meters_per_unit": data.meters_per_unit, "up_axis": data.up_axis,
        "world_offset": list(data.world_offset), "default_lights": data.default_lights,
        "brightest_light": data.brightest_light,
        "prototypes": len(data.prototypes), "grid_media": len(getattr(data, "grid_media", None) or []),
        "translator_version": TRANSLATOR_VERSION,
        "time_code": data.time_code, "shutter": None if data.shutter is None else list(data.shutter),
    }
    table, offset = {}, 0
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        arrays[name] = a
        table[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset}
        offset = _aligned(offset + a.nbytes)
    file_table = {}
    sizes = [os.path.getsize(src) for _, src in files]
    for (name, _), size in zip(files, sizes):
        file_table[name] = {"offset": offset, "size": size}
        offset = _aligned(offset + size)
    header = json.dumps({"meta": meta, "arrays": table, "files": file_table}, separators=(",", ":")).encode()
    start = _aligned(16 + len(header))
    out = bytearray(start + offset)
    out[:16] = MAGIC + struct.pack("<II", BLOB_VERSION, len(header))
    out[16:16 + len(header)] = header
    for name, a in arrays.items():
        o = start + table[name]["offset"]
        out[o:o + a.nbytes] = a.tobytes()  # tobytes: also fine for bool arrays
    for name, src in files:
        o = start + file_table[name]["offset"]
        with open(src, "rb") as f:
            out[o:o + file_table[name]["size"]] = f.read()
    return bytes(out)


def scene_data_from_blob(blob: bytes | bytearray | memoryview) -> SceneData:
    """SceneData from a blob: arrays are read-only views into `blob`."""
    buf = memoryview(blob)
    if len(buf) < 16 or bytes(buf[:8]) != MAGIC:
        raise SceneError("not a Tessera scene blob")
    version, hlen = struct.unpack("<II", buf[8:16])
    if version != BLOB_VERSION:
        raise SceneError(f"scene blob version {version}, this renderer reads version {BLOB_VERSION}")
    try:
        header = json.loads(bytes(buf[16:16 + hlen]))
    except ValueError:
        raise SceneError("corrupt scene blob header") from None
    start = _aligned(16 + hlen)
    arrays = {}
    for name, spec in header["arrays"].items():
        dtype = np.dtype(spec["dtype"])
        count = int(np.prod(spec["shape"], dtype=np.int64))
        end = start + spec["offset"] + count * dtype.itemsize
        if end > len(buf):
            raise SceneError("truncated scene blob")
        arrays[name] = np.frombuffer(buf, dtype=dtype, count=count,
                                     offset=start + spec["offset"]).reshape(spec["shape"])
    meta = header["meta"]
    tmp = None
    rename: dict[str, str] = {}
    if header["files"]:
        # The pid in the name lets a worker's next start remove it after a kill.
        tmp = tempfile.mkdtemp(prefix=f"tessera-blob-{os.getpid()}-")
        for name, spec in header["files"].items():
            target = Path(tmp, *name.split("/"))
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(buf[start + spec["offset"]:start + spec["offset"] + spec["size"]])
            rename[name] = str(target)
    textures = []
    for tex in meta["textures"]:
        tex = dict(tex)
        if tex.get("udim_files") is not None:
            tex["udim_files"] = [rename[n] for n in tex["udim_files"]]
            tex["file"] = os.path.join(tmp, *tex["file"].split("/")) if tmp else tex["file"]
        else:
            tex["file"] = rename.get(tex["file"], tex["file"])
        textures.append(tex)
    dome = meta["dome_light"]
    if dome and dome.get("texture"):
        dome = {**dome, "texture": rename[dome["texture"]]}
    cam = meta["camera"]
    prototypes = [{f: arrays.get(f"prototypes.{i}.{f}") for f in _PROTO_FIELDS} for i in range(meta["prototypes"])]
    data = SceneData(
        positions=arrays["positions"], indices=arrays["indices"], triangle_material=arrays["triangle_material"],
        albedo=arrays["albedo"], emission=arrays["emission"], two_sided_emission=arrays["two_sided_emission"],
        sphere_lights=arrays["sphere_lights"],
        # JSON has no infinity: a None float (clip_far) was one; motion None is no motion.
        camera=CameraDesc(**{k: tuple(v) if isinstance(v, list) else (math.inf if v is None and k != "motion" else v)
                             for k, v in cam.items()}),
        resolution=tuple(meta["resolution"]), resolution_from_stage=meta["resolution_from_stage"],
        warnings=list(meta["warnings"]),
        material_params={k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith("material_params.")},
        shading_normals=arrays.get("shading_normals"), uvs=arrays.get("uvs"),
        textures=textures, material_textures={(m, n): t for m, n, t in meta["material_textures"]},
        distant_lights=arrays["distant_lights"], point_lights=arrays["point_lights"], dome_light=dome,
        prototypes=prototypes, instances=arrays["instances"], instance_transforms=arrays["instance_transforms"],
        meters_per_unit=meta["meters_per_unit"], up_axis=meta["up_axis"],
        world_offset=tuple(meta["world_offset"]), default_lights=meta.get("default_lights"),
        brightest_light=meta.get("brightest_light"),
        motion_instances=arrays.get("motion_instances", np.zeros(0, np.uint32)),
        motion_time_steps=arrays.get("motion_time_steps", np.zeros(0, np.uint32)),
        motion_transforms=arrays.get("motion_transforms", np.zeros((0, 4, 4), np.float32)),
        **{k: arrays[k] for k in _LIGHT_MOTION_FIELDS if k in arrays},
        material_shaping=arrays.get("material_shaping"),
        ies_tables=arrays.get("ies_tables"),
        media=arrays.get("media"), material_media=arrays.get("material_media"),
        curves={k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith("curves.")} or None,
        light_links={k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith("light_links.")} or None,
        light_rows={k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith("light_rows.")},
        grid_media=[tuple(arrays[f"grid_media.{i}.{f}"] for f in ("density", "world_to_index", "coefficients"))
                    for i in range(meta.get("grid_media", 0))],
        material_interface_only=arrays.get("material_interface_only"),
        time_code=meta.get("time_code"),
        shutter=None if meta.get("shutter") is None else tuple(meta["shutter"]))
    if tmp:
        data._blob_files = _Dir(tmp)
    return data


def scene_from_blob(blob: bytes | bytearray | memoryview, default_light: bool = True):
    """The Scene (BVH built) for a blob from translate_to_blob; `default_light` as in Scene."""
    from . import Scene

    return Scene(scene_data_from_blob(blob), default_light=default_light)


class _Dir:
    """Removes a private directory once nothing refers to it."""

    def __init__(self, path: str):
        self.path = path
        self._finalizer = weakref.finalize(self, shutil.rmtree, path, True)


def _udim_files(pattern: str) -> list[str]:
    import glob
    return sorted(glob.glob(pattern.replace("<UDIM>", "1[0-9][0-9][0-9]")))


def _aligned(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN
