"""A Cornell box written the way exporters write a plain diffuse material (UsdPreviewSurface,
useSpecularWorkflow 1, specularColor 0, roughness 1; a one-sided emissive quad) must render
as Lambert: Tessera's path tracer against Mitsuba 3 rendering the same geometry with
Lambertian BSDFs. The Mitsuba scene is built from the USD file with pxr (meshes, world
transforms, material bindings, camera), not from Tessera's translation.

Power: every region mean must agree within 1.5 %, and the combined standard error of each
ratio is required to be below 0.35 %, so a 2 % error is seen; the negative control re-runs
the same check with Mitsuba's image scaled by 0.98 and requires it to fail in every region.
(Before the energy-conserving layering the ratio was about 0.8.)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tessera_tools import peer_mitsuba

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade  # noqa: E402

RES = 40
SPP = 2048
TOL = 0.015
ALBEDO = {"white": (0.725, 0.71, 0.68), "red": (0.63, 0.065, 0.05), "green": (0.14, 0.45, 0.091)}
LE = (17.0, 12.0, 4.0)
TAN_HALF = math.tan(math.radians(24.0))

# Unit box open towards +z (the camera): (name, material, four corners counter-clockwise).
QUADS = [
    ("floor", "white", [(0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 0)]),
    ("ceiling", "white", [(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)]),
    ("back", "white", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]),
    ("left", "red", [(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)]),
    ("right", "green", [(1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0)]),
    # The light faces down (-y): counter-clockwise seen from below.
    ("light", "light", [(0.35, 0.999, 0.35), (0.65, 0.999, 0.35), (0.65, 0.999, 0.65), (0.35, 0.999, 0.65)]),
]


def write_usd(path: Path) -> None:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    mats = {}
    for name in list(ALBEDO) + ["light"]:
        mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/PreviewSurface")
        sh.CreateIdAttr("UsdPreviewSurface")
        sh.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        sh.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
        sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
        diffuse = ALBEDO.get(name, (0.0, 0.0, 0.0))
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
        if name == "light":
            sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*LE))
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        mats[name] = mat
    # The box sits under a transform, as exported scenes do; the reader must apply it.
    box = UsdGeom.Xform.Define(stage, "/World/Box")
    box.AddTranslateOp().Set(Gf.Vec3d(-0.5, 0.0, -0.5))
    for name, mat, corners in QUADS:
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Box/{name}")
        mesh.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        mesh.CreateDoubleSidedAttr(False)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mats[mat])
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.5, 1.7))
    cam.CreateFocalLengthAttr(10.0)
    cam.CreateHorizontalApertureAttr(20.0 * TAN_HALF)
    cam.CreateVerticalApertureAttr(20.0 * TAN_HALF)
    stage.GetRootLayer().Save()


def mitsuba_scene_from_usd(path: Path, mesh_dir: Path) -> dict:
    """Mitsuba scene read from the USD file itself: each mesh (world transform applied,
    fan-triangulated) with a two-sided Lambertian BSDF of its bound diffuseColor and, if
    emissive, a one-sided area emitter; the camera from its transform and apertures."""
    import mitsuba as mi

    stage = Usd.Stage.Open(str(path))
    scene: dict = {"type": "scene", "integrator": {"type": "path", "max_depth": 65}}
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            xf = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
            pts = [xf.Transform(Gf.Vec3d(p)) for p in mesh.GetPointsAttr().Get()]
            counts, idx = mesh.GetFaceVertexCountsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get()
            tris, k = [], 0
            for n in counts:
                tris += [(idx[k], idx[k + j], idx[k + j + 1]) for j in range(1, n - 1)]
                k += n
            shader = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0].ComputeSurfaceSource()[0]
            diffuse = shader.GetInput("diffuseColor").Get()
            emissive = shader.GetInput("emissiveColor")
            obj = mesh_dir / f"{prim.GetName()}.obj"
            lines = [f"v {p[0]} {p[1]} {p[2]}" for p in pts] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tris]
            obj.write_text("\n".join(lines) + "\n")
            entry = {"type": "obj", "filename": str(obj), "face_normals": True,
                     "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance":
                                                           {"type": "rgb", "value": [float(c) for c in diffuse]}}}}
            if emissive and emissive.Get() is not None and max(emissive.Get()) > 0:
                entry["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": [float(c) for c in emissive.Get()]}}
            scene[prim.GetName()] = entry
        elif prim.IsA(UsdGeom.Camera):
            cam = UsdGeom.Camera(prim)
            xf = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
            origin = xf.Transform(Gf.Vec3d(0, 0, 0))
            target = xf.Transform(Gf.Vec3d(0, 0, -1))
            up = xf.TransformDir(Gf.Vec3d(0, 1, 0))
            tan_w = cam.GetHorizontalApertureAttr().Get() / (2.0 * cam.GetFocalLengthAttr().Get())
            scene["sensor"] = {
                "type": "perspective", "fov_axis": "x", "fov": math.degrees(2.0 * math.atan(tan_w)),
                "to_world": mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up)),
                "film": {"type": "hdrfilm", "width": RES, "height": RES, "pixel_format": "rgb",
                         "component_format": "float32", "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": SPP},
            }
    return scene


def region_masks() -> dict[str, np.ndarray]:
    """Pixels whose centre ray hits one wall at least 0.08 from its edges (and not the
    light), from the analytic geometry of the box (camera at (0, 0.5, 1.7) looking -z)."""
    s = (np.arange(RES) + 0.5) / RES * 2 - 1
    tx, ty = np.meshgrid(s * TAN_HALF, -s * TAN_HALF)  # row 0 is the top of the image
    o = np.array([0.0, 0.5, 1.7])
    d = np.stack([tx, ty, -np.ones_like(tx)], -1)
    planes = {"left": (0, -0.5), "right": (0, 0.5), "floor": (1, 0.0), "ceiling": (1, 1.0), "back": (2, -0.5)}
    best = np.full(tx.shape, np.inf)
    label = np.full(tx.shape, "", dtype=object)
    for name, (axis, value) in planes.items():
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - o[axis]) / d[..., axis]
        p = o + t[..., None] * d
        inside = (t > 0) & (np.abs(p[..., 0]) <= 0.5 + 1e-9) & (p[..., 1] >= -1e-9) & (p[..., 1] <= 1 + 1e-9) & \
                 (p[..., 2] >= -0.5 - 1e-9) & (p[..., 2] <= 0.5 + 1e-9)
        margin = 0.08
        away = (np.abs(p[..., 0]) <= 0.5 - margin if axis != 0 else True) & \
               ((p[..., 1] >= margin) & (p[..., 1] <= 1 - margin) if axis != 1 else True) & \
               ((p[..., 2] >= -0.5 + margin) & (p[..., 2] <= 0.5 - margin) if axis != 2 else True)
        if name == "ceiling":
            away = away & ~((np.abs(p[..., 0]) < 0.15 + margin) & (np.abs(p[..., 2]) < 0.15 + margin))
        hit = inside & (t < best)
        best = np.where(hit, t, best)
        label = np.where(hit, np.where(away, name, ""), label)
    return {name: label == name for name in planes}


def region_ratio(tess: np.ndarray, mts: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: Tessera's region mean over Mitsuba's, and the standard error of that
    ratio. The error is taken from the per-pixel differences, which hold the two renders'
    noise but not the shading gradient across the wall."""
    a, b = tess[mask].astype(np.float64), mts[mask].astype(np.float64)
    mb = b.mean(0)
    return a.mean(0) / mb, (a - b).std(0, ddof=1) / math.sqrt(len(a)) / mb


@pytest.mark.skipif(not peer_mitsuba.available(), reason="mitsuba is missing (pip install -e '.[test]')")
def test_usd_cornell_box_of_plain_diffuse_preview_surfaces_renders_as_lambert(tmp_path):
    from tessera_renderer import load_scene

    usd = tmp_path / "cornell.usda"
    write_usd(usd)
    scene = load_scene(usd)
    tess = scene.render_tile(0, 0, RES, RES, width=RES, height=RES, spp=SPP, seed=3, threads=2,
                             integrator="path")[..., :3]
    mi = peer_mitsuba.set_variant("scalar_rgb", threads=2)
    mts = peer_mitsuba.render(mi.load_dict(mitsuba_scene_from_usd(usd, tmp_path)), spp=SPP, seed=5)

    masks = region_masks()
    report = []
    for name, mask in masks.items():
        assert mask.sum() >= 20, f"region {name} has only {mask.sum()} pixels"
        ratios, ses = region_ratio(tess, mts, mask)
        for c in range(3):
            ratio, se = float(ratios[c]), float(ses[c])
            report.append((name, c, ratio, se))
            assert se < 0.0035, f"{name} channel {c}: standard error {se:.4f} too large to see 2 %"
            assert abs(ratio - 1) < TOL, f"{name} channel {c}: Tessera/Mitsuba = {ratio:.4f}"
            # Negative control: the same check against a 2 % dimmer reference must fail.
            assert abs(ratio / 0.98 - 1) >= TOL, f"{name} channel {c}: 2 % would go unseen"
    print("\n".join(f"{n} ch{c}: ratio {r:.4f} +- {s:.4f}" for n, c, r, s in report))
