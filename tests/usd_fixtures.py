"""Small USD scenes written with pxr for tests: each one has a known answer."""
from __future__ import annotations

from pathlib import Path

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade


def new_stage(path: Path) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    return stage


def add_material(stage, path: str, diffuse=(0.5, 0.5, 0.5), emissive=(0.0, 0.0, 0.0)) -> UsdShade.Material:
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path + "/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def emission_only(stage, path: str = "/EmissionOnly") -> None:
    """Marks a test rig whose emitters are its only light: a UsdLux light makes a stage lit
    whatever its emission, and one of intensity 0 adds nothing (no emitter), so the rig
    renders as authored instead of getting the default lighting a stage gets when its
    emission is weak against the scene's size (docs/scene-translation.md)."""
    UsdLux.DistantLight.Define(stage, path).CreateIntensityAttr(0.0)


def add_mesh(stage, path: str, points, counts, indices, material=None, double_sided=False):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in points])
    mesh.CreateFaceVertexCountsAttr(list(counts))
    mesh.CreateFaceVertexIndicesAttr(list(indices))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(double_sided)
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def add_camera(stage, path: str, translate=(0, 0, 0), focal=50.0, haperture=36.0, vaperture=36.0):
    cam = UsdGeom.Camera.Define(stage, path)
    cam.AddTranslateOp().Set(Gf.Vec3d(*translate))
    cam.CreateFocalLengthAttr(focal)
    cam.CreateHorizontalApertureAttr(haperture)
    cam.CreateVerticalApertureAttr(vaperture)
    return cam


def add_render_settings(stage, camera, resolution=(32, 32)):
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(*resolution))
    settings.CreateCameraRel().SetTargets([camera.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    return settings


def box_inward_faces(lo, hi):
    """Points and quads of an axis-aligned box, wound to face inward."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    pts = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return pts, [4] * 6, [i for q in quads for i in q]


def write_furnace(path: Path, albedo: float, emission=(0.5, 1.0, 2.0), resolution=(24, 24), *,
                  metallic: float | None = None, roughness: float | None = None) -> Path:
    """A closed box, every wall a UsdPreviewSurface of diffuseColor `albedo` emitting Le,
    seen from inside. With metallic 1 and roughness 0 each wall reflects `albedo` at every
    angle, so the radiance is Le / (1 - albedo) everywhere."""
    stage = new_stage(path)
    mat = add_material(stage, "/Looks/Wall", (albedo,) * 3, emission)
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Wall/Surface"))
    if metallic is not None:
        shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(metallic)
    if roughness is not None:
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    pts, counts, idx = box_inward_faces((-2, -1, -3), (1, 2, 1))
    add_mesh(stage, "/World/Box", pts, counts, idx, mat, double_sided=True)
    cam = add_camera(stage, "/World/Camera", (0.1, 0.2, 0.3), focal=20.0)
    add_render_settings(stage, cam, resolution)
    stage.GetRootLayer().Save()
    return path


def write_rect_light_facing_camera(path: Path, *, width=2.0, height=3.0, intensity=1.0, exposure=0.0,
                                   color=(1.0, 1.0, 1.0), normalize=False, scale=1.0) -> Path:
    """A RectLight at z=-5 facing the camera at the origin (it emits along its local -Z, so it
    is turned half round), large enough to fill the central pixels."""
    stage = new_stage(path)
    xf = UsdGeom.Xform.Define(stage, "/World/LightXf")
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5))
    xf.AddRotateYOp().Set(180.0)
    xf.AddScaleOp().Set(Gf.Vec3f(scale, scale, scale))
    light = UsdLux.RectLight.Define(stage, "/World/LightXf/Light")
    light.CreateWidthAttr(width)
    light.CreateHeightAttr(height)
    light.CreateIntensityAttr(intensity)
    light.CreateExposureAttr(exposure)
    light.CreateColorAttr(Gf.Vec3f(*color))
    light.CreateNormalizeAttr(normalize)
    cam = add_camera(stage, "/World/Camera", (0, 0, 0), focal=100.0, haperture=4.0, vaperture=4.0)
    add_render_settings(stage, cam, (8, 8))
    stage.GetRootLayer().Save()
    return path


# A Blender export's hair scene: one SphereLight of intensity 10 (the exporter's value,
# W-less) 40 units above a grey floor in a scene of metres: its image is dim, not wrong.
DIM_SPHERE_LIGHT_USDA = """#usda 1.0
(upAxis = "Y")
def Camera "Cam" {
    double3 xformOp:translate = (0, 1, 6)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def SphereLight "Light" {
    float inputs:radius = 0.1
    float inputs:intensity = INTENSITY
    double3 xformOp:translate = (0, 40, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def SphereLight "Fill" {
    float inputs:radius = 0.1
    float inputs:intensity = 2
    double3 xformOp:translate = (3, 40, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Mesh "Floor" {
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)]
}
"""


def save_stage(stage) -> str:
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


def add_quad(stage, path="/Quad", size=1.0, z=0.0, material=None, display=None):
    s = size
    mesh = add_mesh(stage, path, [(-s, -s, z), (s, -s, z), (s, s, z), (-s, s, z)], [4], [0, 1, 2, 3],
                    material=material)
    if display is not None:
        mesh.CreateDisplayColorAttr([Gf.Vec3f(*display)])
    return mesh


def lightless_quad(tmp_path, albedo=0.5):
    stage = new_stage(tmp_path / "prop.usda")
    add_quad(stage, display=(albedo, albedo, albedo))
    return save_stage(stage)


def write_four_texel_png(path):
    """2 x 2 texels, rows top to bottom: red, green / blue, white. In st (t up):
    (0.25, 0.25) is blue, (0.75, 0.75) green, (0.75, 0.25) white, (0.25, 0.75) red."""
    import numpy as np
    import OpenImageIO as oiio

    px = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], np.uint8)
    oiio.ImageBuf(px).write(str(path))
