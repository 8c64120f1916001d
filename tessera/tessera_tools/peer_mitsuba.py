"""Mitsuba 3 as a peer renderer: the same scene, built from Tessera's own translation.

`tessera bench` renders a scene with Tessera and with Mitsuba in the same run, so the two
must see the same thing. Nothing is re-read from USD here: the triangles, materials,
lights and camera all come from Tessera's `SceneData`.

What is matched, and how (anything else raises `Unmatched`, so a comparison never runs on
a scene the two renderers would see differently):

| Tessera (SceneData)                               | Mitsuba 3                                    |
|---------------------------------------------------|----------------------------------------------|
| triangles of one material row                     | one PLY mesh (unshared vertices)             |
| corner shading normals                            | the mesh's vertex normals                    |
| Lambertian row (not a UsdPreviewSurface)          | `twosided` `diffuse`, reflectance = albedo   |
| UsdPreviewSurface, opacity 0, roughness < 0.032,  | `dielectric`, int_ior = ior, ext_ior = 1     |
|   no clearcoat (smooth glass; untinted)           |                                              |
| UsdPreviewSurface, metallic 1, roughness < 0.032, | `twosided` `conductor`, material none,       |
|   opacity 1, no clearcoat, metallic workflow      |   specular_reflectance = diffuseColor        |
| emission (radiance) on a row                      | `area` emitter, radiance = emission          |
| sphere light (centre, radius, radiance)           | `sphere` shape + `area` emitter, black BSDF  |
| pinhole camera (origin, forward, up, tan_w)       | `perspective`, fov_axis x, look_at           |
| box pixel filter, linear float RGBA               | `hdrfilm` rgb float32 with `box` rfilter     |

Why Lambertian rows only for opaque diffuse surfaces: Tessera's UsdPreviewSurface with
metallic 0 keeps a GGX specular lobe (F0 from ior, F90 = min(1, 50 F0)) with Kulla-Conty
compensation over an albedo-scaled diffuse (docs/materials.md); no Mitsuba BSDF has that
model. (With ior 1 or specularColor 0 it is exactly Lambert.)
`lambertize()` turns such rows into plain Lambertian ones (same albedo) for *both*
renderers when a comparison wants them.

Conventions checked against Tessera (and shown by the unit-agreement check in
`tessera bench`): emitter values are radiance on both sides (Mitsuba's `area` radiance;
Tessera's UsdLux translation, design notes "USD light units"); area emitters are
one-sided along the geometric normal on both sides unless the row is two-sided, which is
built as a second, flipped mesh; Mitsuba BSDFs are one-sided, Tessera's opaque ones are
two-sided, hence `twosided`. Mitsuba's default pixel filter is a Gaussian; Tessera
averages uniformly jittered samples inside the pixel, i.e. a box filter, so the film uses
`box`. Mitsuba's `spp` is samples per pixel like Tessera's.
"""
from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

SMOOTH_ROUGHNESS = 0.032     # alpha = roughness^2 < 1e-3: Tessera's delta lobes


class Unmatched(ValueError):
    """The scene uses something Tessera and Mitsuba would not render alike."""


_LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
               "/usr/lib/llvm-19/lib/libLLVM.so*",
               "/usr/lib/x86_64-linux-gnu/libLLVM-19.so*")


def available() -> bool:
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return False
    return True


def set_variant(name: str = "scalar_rgb", threads: int = 2):
    """Selects a Mitsuba variant and the size of its thread pool. For `llvm_*`, points Dr.Jit
    at Debian's LLVM 19 if DRJIT_LIBLLVM_PATH is unset. Returns the mitsuba module, or
    raises RuntimeError with the reason the variant cannot run here."""
    if name.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        import glob

        for pattern in _LLVM_GLOBS:
            hits = sorted(glob.glob(pattern))
            if hits:
                os.environ["DRJIT_LIBLLVM_PATH"] = hits[0]
                break
    import drjit as dr
    import mitsuba as mi

    try:
        mi.set_variant(name)
    except Exception as exc:  # noqa: BLE001 - Mitsuba raises plain exceptions for this
        raise RuntimeError(f"Mitsuba variant {name} is not usable here: {exc}") from None
    # The scalar variants render blocks on Dr.Jit's thread pool; the LLVM variants run their
    # kernels on the same pool. Either way this sets the number of render threads.
    dr.set_thread_count(threads)
    return mi


def lambertize(data):
    """A copy of SceneData whose opaque non-metal UsdPreviewSurface rows are plain
    Lambertian (same diffuseColor): the model both renderers have. Glass and smooth metal
    rows stay as they are (they are matched exactly)."""
    params = {k: np.array(v, copy=True) for k, v in data.material_params.items()}
    if "preview_surface" not in params:
        return data
    preview = params["preview_surface"].astype(bool)
    opaque = (params["opacity"] >= 1.0) & (params["metallic"] <= 0.0) & (params["clearcoat"] <= 0.0)
    params["preview_surface"] = np.where(preview & opaque, 0.0, params["preview_surface"]).astype(np.float32)
    return replace(data, material_params=params)


def exactly_lambertian(p: dict, row: int) -> bool:
    """Whether a UsdPreviewSurface row is exactly a Lambertian of its diffuseColor: opaque, no
    clearcoat, no specular Fresnel at any angle (specularColor 0 in the specular workflow,
    or ior 1 and metallic 0). The core renders such rows as Lambertians
    (bsdf.h, ExactLambertianAlbedo)."""
    if float(p["opacity"][row]) < 1.0 or float(p["clearcoat"][row]) > 0.0:
        return False
    if bool(p["use_specular_workflow"][row]):
        return not np.any(np.asarray(p["specular_color"]).reshape(-1, 3)[row] > 0.0)
    return float(p["metallic"][row]) <= 0.0 and float(p["ior"][row]) == 1.0


def _material(data, row: int) -> dict:
    albedo = [float(x) for x in data.albedo.reshape(-1, 3)[row]]
    p = data.material_params
    if not p or "preview_surface" not in p or not bool(p["preview_surface"][row]):
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}}
    if exactly_lambertian(p, row):
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}}
    rough = float(p["roughness"][row])
    opacity = float(p["opacity"][row])
    coat = float(p["clearcoat"][row])
    metallic = float(p["metallic"][row])
    threshold = float(p["opacity_threshold"][row])
    specular_workflow = bool(p["use_specular_workflow"][row])
    if opacity <= 0.0 and threshold <= 0.0 and rough < SMOOTH_ROUGHNESS and coat <= 0.0:
        return {"type": "dielectric", "int_ior": float(p["ior"][row]), "ext_ior": 1.0}
    if (metallic >= 1.0 and not specular_workflow and opacity >= 1.0 and rough < SMOOTH_ROUGHNESS
            and coat <= 0.0):
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": {"type": "rgb", "value": albedo}}}
    raise Unmatched(f"material row {row}: UsdPreviewSurface (metallic {metallic}, roughness {rough}, "
                    f"opacity {opacity}, clearcoat {coat}) has no matching Mitsuba BSDF; "
                    "use lambertize() to compare on Lambertian surfaces")


def _check_supported(data) -> None:
    if len(getattr(data, "motion_instances", [])) or getattr(data.camera, "motion", None) is not None:
        raise Unmatched("motion blur (moving instances; render with shutter=(0, 0) to compare a still frame)")
    if len(getattr(data, "instances", [])):
        raise Unmatched("instanced geometry (translate with instancing='flatten')")
    if getattr(data, "dome_light", None):
        raise Unmatched("dome light (lat-long conventions not matched)")
    if len(getattr(data, "distant_lights", [])):
        raise Unmatched("distant lights")
    if getattr(data, "material_textures", None):
        raise Unmatched("textured materials")
    if data.camera.lens_radius > 0:
        raise Unmatched("thin-lens camera")
    if getattr(data.camera, "orthographic", False):
        raise Unmatched("orthographic camera")
    if getattr(data.camera, "horizontal_aperture_offset", 0.0) or getattr(data.camera, "vertical_aperture_offset", 0.0):
        raise Unmatched("aperture offsets (a shifted image window)")


def scene_dict(data, width: int, height: int, mesh_dir: str | Path, *, max_depth: int = 64,
               integrator: str = "path", sampler: str = "independent") -> dict:
    """The Mitsuba scene dictionary for Tessera's SceneData at width x height; the meshes
    are written as PLY files (one per material row) into `mesh_dir`. max_depth counts
    bounces like Tessera's (Mitsuba counts path vertices: +1)."""
    import mitsuba as mi

    _check_supported(data)
    materials = data.triangle_material.reshape(-1)
    bsdfs = {int(row): _material(data, int(row)) for row in np.unique(materials)}   # raises first
    cam = data.camera
    tan_w, _ = cam.tan_half_angles(width, height)
    origin = [float(x) for x in cam.origin]
    target = [o + float(f) for o, f in zip(origin, cam.forward)]
    far = cam.clip_far if math.isfinite(cam.clip_far) else 1e7
    scene: dict = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": max_depth + 1},
        "sensor": {
            "type": "perspective",
            "fov_axis": "x",
            "fov": math.degrees(2.0 * math.atan(tan_w)),
            "near_clip": max(float(cam.clip_near), 1e-4),
            "far_clip": float(far),
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target,
                                                       up=[float(x) for x in cam.up]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb",
                     "component_format": "float32", "rfilter": {"type": "box"}},
            # ldsampler wants a square power of two (mi.render overrides it with spp).
            "sampler": {"type": sampler, "sample_count": 1 if sampler == "independent" else 4},
        },
    }
    positions = data.positions.reshape(-1, 3).astype(np.float32)
    tris = data.indices.reshape(-1, 3)
    materials = data.triangle_material.reshape(-1)
    normals = getattr(data, "shading_normals", None)
    emission = data.emission.reshape(-1, 3)
    two_sided = np.asarray(data.two_sided_emission).reshape(-1)
    directory = Path(mesh_dir)
    directory.mkdir(parents=True, exist_ok=True)
    for row in np.unique(materials):
        sel = np.nonzero(materials == row)[0]
        corners = positions[tris[sel]].reshape(-1, 3)                  # unshared vertices
        corner_normals = None if normals is None else np.asarray(normals, np.float32)[sel].reshape(-1, 3)
        bsdf = bsdfs[int(row)]
        radiance = [float(x) for x in emission[row]]
        flips = (False, True) if (max(radiance) > 0 and bool(two_sided[row])) else (False,)
        for flip in flips:
            name = f"mesh_{row}{'_back' if flip else ''}"
            path = directory / f"{name}.ply"
            _write_ply(path, corners, None if corner_normals is None else
                       (-corner_normals if flip else corner_normals), flip)
            entry = {"type": "ply", "filename": str(path), "face_normals": corner_normals is None, "bsdf": bsdf}
            if max(radiance) > 0:
                entry["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": radiance}}
            scene[name] = entry
    for k, (cx, cy, cz, r, lr, lg, lb) in enumerate(np.asarray(data.sphere_lights, np.float64).reshape(-1, 7)):
        scene[f"sphere_light_{k}"] = {
            "type": "sphere", "center": [cx, cy, cz], "radius": r,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [lr, lg, lb]}},
        }
    points = np.asarray(getattr(data, "point_lights", np.zeros((0, 6))), np.float64)
    points = points.reshape(len(points), -1) if len(points) else np.zeros((0, 6))
    if points.shape[1] > 6 and np.any(points[:, 6] != 0):
        raise Unmatched("shaped point lights (UsdLux ShapingAPI cones, IES) have no Mitsuba counterpart here")
    for k, (px, py, pz, ir, ig, ib) in enumerate(points[:, :6]):
        scene[f"point_light_{k}"] = {"type": "point", "position": [px, py, pz],
                                     "intensity": {"type": "rgb", "value": [ir, ig, ib]}}
    return scene


def _write_ply(path: Path, corners: np.ndarray, normals: np.ndarray | None, flip: bool) -> None:
    """Binary PLY: one vertex per triangle corner (with its normal if given), faces in
    order, winding reversed if `flip`."""
    n = len(corners)
    fields = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {f}" for f in fields]
    header += [f"element face {n // 3}", "property list uchar int vertex_indices", "end_header"]
    verts = corners.astype("<f4") if normals is None else np.hstack([corners, normals]).astype("<f4")
    faces = np.arange(n, dtype="<i4").reshape(-1, 3)
    if flip:
        faces = faces[:, ::-1]
    face_rec = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_rec["n"], face_rec["v"] = 3, faces
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(verts).tobytes())
        f.write(face_rec.tobytes())


def render(scene, spp: int, seed: int) -> np.ndarray:
    """Linear RGB float32 (H, W, 3)."""
    import mitsuba as mi

    return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)[..., :3]
