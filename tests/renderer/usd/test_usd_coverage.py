"""USD coverage beyond plain meshes: primvars, subsets, gprims, lights, instancing, time,
textures and the translate-once blob. Expectations come from geometry, the UsdLux /
UsdPreviewSurface specifications and published colorimetry, not from earlier output."""
from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from tessera_renderer import load_scene
from tessera_renderer.usd import gprims
from tessera_renderer.scene_blob import scene_data_from_blob, scene_from_blob, translate_to_blob
from tessera_renderer.usd import translate_stage as _translate_stage
from usd_fixtures import add_camera, add_material, add_mesh, add_render_settings, new_stage

QUAD2 = ([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)], [4, 4], [0, 1, 2, 3, 1, 4, 5, 2])

# These tests read what the translation put where: world coordinates, not the
# camera-relative ones a render uses (test_stability.py tests those).
translate_stage = functools.partial(_translate_stage, camera_relative=False)


def save(stage):
    stage.GetRootLayer().Save()
    return stage.GetRootLayer().realPath


def corner_lookup(data, point):
    """The per-corner rows whose vertex is at `point`."""
    p = data.positions[data.indices]  # (T, 3, 3)
    return np.all(np.isclose(p, point, atol=1e-6), axis=-1)


# -- primvars and normals ------------------------------------------------------------
@pytest.mark.parametrize("interp,values,indices,expected_at_point4", [
    ("constant", [(0.5, 0.25)], None, (0.5, 0.25)),
    ("uniform", [(0.1, 0.1), (0.9, 0.9)], None, (0.9, 0.9)),           # point 4 is only in face 1
    ("vertex", [(k / 10, 0) for k in range(6)], None, (0.4, 0.0)),
    ("faceVarying", [(k / 10, 1) for k in range(8)], None, (0.5, 1.0)),  # point 4 is corner 5
    ("vertex", [(0, 0), (7, 7)], [0, 0, 0, 0, 1, 0], (7.0, 7.0)),       # indexed
])
def test_st_of_every_interpolation_is_expanded_per_corner(tmp_path, interp, values, indices, expected_at_point4):
    stage = new_stage(tmp_path / "st.usda")
    mesh = add_mesh(stage, "/M", *QUAD2)
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    pv.Set([Gf.Vec2f(*v) for v in values])
    if indices is not None:
        pv.SetIndices(Vt.IntArray(indices))
    data = translate_stage(save(stage))
    assert data.uvs.shape == (4, 3, 2) and data.shading_normals is None
    at4 = corner_lookup(data, (2, 0, 0))
    assert at4.sum() >= 1
    np.testing.assert_allclose(data.uvs[at4], np.tile(expected_at_point4, (int(at4.sum()), 1)), rtol=1e-6)


def test_primvars_normals_win_over_normals_and_meshes_without_normals_are_faceted(tmp_path):
    stage = new_stage(tmp_path / "n.usda")
    a = add_mesh(stage, "/A", *QUAD2)
    a.CreateNormalsAttr([Gf.Vec3f(1, 0, 0)] * 6)
    a.SetNormalsInterpolation("vertex")
    pv = UsdGeom.PrimvarsAPI(a).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, "uniform")
    pv.Set([Gf.Vec3f(0, 2, 0), Gf.Vec3f(0, 0, -3)])  # unnormalised on purpose
    add_mesh(stage, "/B", [(0, 0, 5), (1, 0, 5), (0, 1, 5)], [3], [0, 1, 2])
    data = translate_stage(save(stage))
    n = data.shading_normals
    assert n.shape == (5, 3, 3)
    np.testing.assert_allclose(n[:2], np.tile([0, 1, 0], (2, 3, 1)), atol=1e-6)   # face 0, from the primvar
    np.testing.assert_allclose(n[2:4], np.tile([0, 0, -1], (2, 3, 1)), atol=1e-6)  # face 1
    np.testing.assert_allclose(n[4], np.tile([0, 0, 1], (3, 1)), atol=1e-6)        # faceted: the face normal


def test_normals_follow_non_uniform_scale_by_the_inverse_transpose(tmp_path):
    stage = new_stage(tmp_path / "s.usda")
    xf = UsdGeom.Xform.Define(stage, "/X")
    xf.AddScaleOp().Set(Gf.Vec3f(2, 1, 1))
    m = add_mesh(stage, "/X/M", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    m.CreateNormalsAttr([Gf.Vec3f(1, 1, 0)] * 3)
    m.SetNormalsInterpolation("vertex")
    data = translate_stage(save(stage))
    expected = np.array([0.5, 1.0, 0.0]) / np.linalg.norm([0.5, 1.0, 0.0])
    np.testing.assert_allclose(data.shading_normals[0], np.tile(expected, (3, 1)), atol=1e-6)


def test_holes_are_honoured(tmp_path):
    stage = new_stage(tmp_path / "h.usda")
    m = add_mesh(stage, "/M", *QUAD2)
    m.CreateHoleIndicesAttr([0])
    data = translate_stage(save(stage))
    assert len(data.indices) == 2 and data.positions[data.indices][..., 0].min() >= 1.0


# -- materials -------------------------------------------------------------------------
def test_geom_subsets_bind_their_own_materials(tmp_path):
    stage = new_stage(tmp_path / "g.usda")
    red = add_material(stage, "/Looks/Red", (1, 0, 0))
    blue = add_material(stage, "/Looks/Blue", (0, 0, 1))
    mesh = add_mesh(stage, "/M", *QUAD2, material=red)
    subset = UsdGeom.Subset.CreateGeomSubset(mesh, "right", UsdGeom.Tokens.face, Vt.IntArray([1]),
                                             UsdShade.Tokens.materialBind)
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(blue)
    data = translate_stage(save(stage))
    albedo = data.albedo[data.triangle_material]
    left = data.positions[data.indices][:, :, 0].max(axis=1) <= 1.0
    np.testing.assert_allclose(albedo[left], np.tile([1, 0, 0], (int(left.sum()), 1)))
    np.testing.assert_allclose(albedo[~left], np.tile([0, 0, 1], (int((~left).sum()), 1)))


def test_material_binding_is_inherited_and_collection_bindings_apply(tmp_path):
    stage = new_stage(tmp_path / "b.usda")
    green = add_material(stage, "/Looks/Green", (0, 1, 0))
    grey = add_material(stage, "/Looks/Grey", (0.3, 0.3, 0.3))
    parent = UsdGeom.Xform.Define(stage, "/P")
    UsdShade.MaterialBindingAPI.Apply(parent.GetPrim()).Bind(green)
    add_mesh(stage, "/P/Inherits", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    add_mesh(stage, "/Q/ByCollection", [(0, 0, 2), (1, 0, 2), (0, 1, 2)], [3], [0, 1, 2])
    root = stage.DefinePrim("/Q")
    coll = Usd.CollectionAPI.Apply(root, "greys")
    coll.CreateIncludesRel().AddTarget("/Q/ByCollection")
    UsdShade.MaterialBindingAPI.Apply(root).Bind(coll, grey, "greys")
    data = translate_stage(save(stage))
    albedo = data.albedo[data.triangle_material]
    np.testing.assert_allclose(albedo[0], (0, 1, 0))
    np.testing.assert_allclose(albedo[1], (0.3, 0.3, 0.3), rtol=1e-6)


def test_preview_surface_parameters_defaults_and_textures(tmp_path):
    import OpenImageIO as oiio
    oiio.ImageBuf(np.zeros((8, 4, 1), np.uint16)).write(str(tmp_path / "rough.png"))
    stage = new_stage(tmp_path / "p.usda")
    mat = add_material(stage, "/Looks/M", (0.2, 0.4, 0.6))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface"))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.7)
    shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.1, 0.2, 0.3))
    tex = UsdShade.Shader.Define(stage, "/Looks/M/Rough")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./rough.png")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 2))
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.35, 0, 0, 1))
    reader = UsdShade.Shader.Define(stage, "/Looks/M/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("uvSet2")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "r")
    add_mesh(stage, "/M", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2], mat)
    data = translate_stage(save(stage))
    p = data.material_params
    m = int(data.triangle_material[0])
    np.testing.assert_allclose(data.albedo[m], (0.2, 0.4, 0.6), rtol=1e-6)
    assert p["metallic"][m] == pytest.approx(0.7)
    assert p["roughness"][m] == pytest.approx(0.35)            # the texture's fallback, channel r
    assert p["ior"][m] == pytest.approx(1.5) and p["opacity"][m] == 1.0  # Sdr defaults
    assert p["clearcoat_roughness"][m] == pytest.approx(0.01)
    assert p["use_specular_workflow"][m] == 1.0
    np.testing.assert_allclose(p["specular_color"][m], (0.1, 0.2, 0.3), rtol=1e-6)
    t = data.textures[data.material_textures[(m, "roughness")]]
    assert t["file"] == str(tmp_path / "rough.png") and t["channel"] == "r"
    assert t["wrap_s"] == "repeat" and t["wrap_t"] == "useMetadata"
    assert t["scale"] == [2, 2, 2, 2] and t["bias"] == [0, 0, 0, 0]
    assert t["color_space"] == "raw"  # auto + 16-bit image
    assert t["st_primvar"] == "uvSet2"
    assert (t["width"], t["height"]) == (4, 8)


# -- gprims ----------------------------------------------------------------------------
def _area_volume(pts, tris):
    p = pts[tris]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return 0.5 * np.linalg.norm(cross, axis=1).sum(), np.einsum("ij,ij->i", p[:, 0], cross).sum() / 6


@pytest.mark.parametrize("shape,area,volume", [
    (lambda: gprims.sphere(2.0), 4 * math.pi * 4, 4 / 3 * math.pi * 8),
    (lambda: gprims.cube(3.0), 54.0, 27.0),
    (lambda: gprims.cylinder(1.0, 2.0, "X"), 2 * math.pi * 2 + 2 * math.pi, math.pi * 2),
    (lambda: gprims.cone(1.0, 3.0, "Y"), math.pi * (1 + math.sqrt(10)), math.pi * 3 / 3),
    (lambda: gprims.capsule(0.5, 2.0, "Z"), 2 * math.pi * 0.5 * 2 + 4 * math.pi * 0.25,
     math.pi * 0.25 * 2 + 4 / 3 * math.pi * 0.125),
])
def test_gprim_tessellation_has_the_true_area_and_outward_winding(shape, area, volume):
    pts, tris, normals = shape()
    a, v = _area_volume(pts, tris)
    assert a == pytest.approx(area, rel=0.01)
    assert v == pytest.approx(volume, rel=0.01)  # positive: the winding faces outward


def test_gprims_in_a_stage_take_their_axis_size_and_transform(tmp_path):
    stage = new_stage(tmp_path / "gp.usda")
    cyl = UsdGeom.Cylinder.Define(stage, "/C")
    cyl.CreateAxisAttr("X")
    cyl.CreateHeightAttr(4.0)
    cyl.CreateRadiusAttr(0.5)
    cyl.AddTranslateOp().Set(Gf.Vec3d(0, 10, 0))
    plane = UsdGeom.Plane.Define(stage, "/P")
    plane.CreateWidthAttr(2.0)
    plane.CreateLengthAttr(6.0)
    plane.CreateAxisAttr("Y")
    data = translate_stage(save(stage))
    p = data.positions
    c = p[p[:, 1] > 5]
    np.testing.assert_allclose(c.min(axis=0), (-2, 9.5, -0.5), atol=1e-6)
    np.testing.assert_allclose(c.max(axis=0), (2, 10.5, 0.5), atol=1e-6)
    pl = data.positions[data.indices[-2:]].reshape(-1, 3)
    assert np.ptp(pl[:, 1]) == 0  # the plane is flat in y
    assert sorted(np.ptp(pl, axis=0).round(6).tolist()) == [0.0, 2.0, 6.0]


# -- visibility, purpose, time, activation ---------------------------------------------
def test_purpose_activation_and_frames(tmp_path):
    stage = new_stage(tmp_path / "t.usda")
    tri = ([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    add_mesh(stage, "/Render", *tri).CreatePurposeAttr("render")
    add_mesh(stage, "/Proxy", *tri).CreatePurposeAttr("proxy")
    add_mesh(stage, "/Off", *tri).GetPrim().SetActive(False)
    moving = UsdGeom.Xform.Define(stage, "/Moving")
    op = moving.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 1.0)
    op.Set(Gf.Vec3d(0, 0, 10), 11.0)
    add_mesh(stage, "/Moving/M", *tri)
    path = save(stage)
    assert len(translate_stage(path, frame=1).indices) == 2
    z6 = translate_stage(path, frame=6).positions[:, 2]
    assert z6.max() == pytest.approx(5.0)  # linear interpolation halfway


# -- lights ---------------------------------------------------------------------------
def _facing_light(tmp_path, kind, **attrs):
    stage = new_stage(tmp_path / f"{kind}.usda")
    xf = UsdGeom.Xform.Define(stage, "/Lx")
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5))
    xf.AddRotateYOp().Set(180.0)  # emits along local -Z: turned to face the camera
    light = getattr(UsdLux, kind).Define(stage, "/Lx/L")
    for k, v in attrs.items():
        light.GetPrim().CreateAttribute(f"inputs:{k}", _type(v)).Set(v)
    add_render_settings(stage, add_camera(stage, "/Cam", (0, 0, 0), focal=100.0, haperture=2.0,
                                          vaperture=2.0), (4, 4))
    return save(stage)


def _type(v):
    return Sdf.ValueTypeNames.Bool if isinstance(v, bool) else Sdf.ValueTypeNames.Float


@pytest.mark.parametrize("attrs,expected", [
    (dict(radius=2.0, intensity=1.0), 1.0),
    (dict(radius=2.0, intensity=4 * math.pi, normalize=True), 1.0),   # area pi r^2 = 4 pi
    (dict(radius=2.0, intensity=3.0, exposure=1.0), 6.0),
])
def test_disk_light_seen_head_on_has_the_usdlux_radiance(tmp_path, attrs, expected):
    scene = load_scene(_facing_light(tmp_path, "DiskLight", **attrs))
    img = scene.render_tile(0, 0, 4, 4, spp=2)
    np.testing.assert_allclose(img[..., :3], expected, rtol=1e-5)


def test_disk_light_is_one_sided(tmp_path):
    stage = new_stage(tmp_path / "d.usda")
    light = UsdLux.DiskLight.Define(stage, "/L")   # emits along -Z, the camera is at -Z... behind
    light.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5))
    light.CreateRadiusAttr(2.0)
    add_render_settings(stage, add_camera(stage, "/Cam", focal=100.0, haperture=2.0, vaperture=2.0), (4, 4))
    img = load_scene(save(stage)).render_tile(0, 0, 4, 4, spp=2)
    assert img[..., :3].max() == 0.0


def test_cylinder_light_radiance_uses_its_side_area(tmp_path):
    stage = new_stage(tmp_path / "c.usda")
    light = UsdLux.CylinderLight.Define(stage, "/L")   # along X; the camera looks at its side
    light.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5))
    light.CreateRadiusAttr(1.0)
    light.CreateLengthAttr(8.0)
    light.CreateIntensityAttr(2 * math.pi * 1.0 * 8.0 * 3.0)
    light.CreateNormalizeAttr(True)
    add_render_settings(stage, add_camera(stage, "/Cam", focal=100.0, haperture=1.0, vaperture=1.0), (4, 4))
    data = translate_stage(save(stage))
    np.testing.assert_allclose(data.emission[data.emission.any(axis=1)], [[3.0, 3.0, 3.0]], rtol=1e-6)
    img = load_scene(save(stage)).render_tile(0, 0, 4, 4, spp=2)
    np.testing.assert_allclose(img[..., :3], 3.0, rtol=1e-5)


def test_distant_point_and_dome_light_tables(tmp_path):
    stage = new_stage(tmp_path / "l.usda")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.AddRotateXOp().Set(90.0)          # local -Z -> world +Y... rotated: travels along +Y
    sun.CreateAngleAttr(1.0)
    sun.CreateIntensityAttr(2.0)
    bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
    bulb.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    bulb.CreateTreatAsPointAttr(True)
    bulb.CreateIntensityAttr(8.0)
    bulb.CreateNormalizeAttr(True)
    dome = UsdLux.DomeLight.Define(stage, "/Dome")
    dome.CreateIntensityAttr(0.5)
    dome.CreateColorAttr(Gf.Vec3f(1, 0.5, 0.25))
    data = translate_stage(save(stage))
    d = data.distant_lights
    assert d.shape == (1, 7)
    np.testing.assert_allclose(d[0, :3], (0, 1, 0), atol=1e-6)
    assert d[0, 3] == pytest.approx(math.radians(0.5))
    np.testing.assert_allclose(d[0, 4:], 2.0)
    np.testing.assert_allclose(data.point_lights, [[1, 2, 3, 2, 2, 2]], rtol=1e-6)  # I/4 W/sr
    np.testing.assert_allclose(data.dome_light["radiance"], (0.5, 0.25, 0.125))
    # Z-up stage, poleAxis "scene": the map's pole (light +Y) is world +Z.
    w2l = np.array(data.dome_light["world_to_light"])
    np.testing.assert_allclose(w2l @ [0, 0, 1], [0, 1, 0], atol=1e-9)


@pytest.mark.parametrize("kelvin,xy", [(2856, (0.4476, 0.4074)),    # CIE illuminant A
                                       (5000, (0.3451, 0.3516)),
                                       (6504, (0.3135, 0.3236)),
                                       (10000, (0.2807, 0.2884))])
def test_blackbody_colour_matches_the_planckian_locus(kelvin, xy):
    rgb = gprims.blackbody_rgb(kelvin)
    rgb_to_xyz = np.array([[0.4124564, 0.3575761, 0.1804375],
                           [0.2126729, 0.7151522, 0.0721750],
                           [0.0193339, 0.1191920, 0.9503041]])
    X, Y, Z = rgb_to_xyz @ rgb
    assert Y == pytest.approx(1.0, rel=1e-6)
    assert (X / (X + Y + Z), Y / (X + Y + Z)) == pytest.approx(xy, abs=2e-3)


def test_color_temperature_tints_the_radiance(tmp_path):
    data = translate_stage(_facing_light(tmp_path, "DiskLight", radius=1.0, intensity=1.0,
                                         enableColorTemperature=True, colorTemperature=3000.0))
    e = data.emission[data.emission.any(axis=1)][0]
    np.testing.assert_allclose(e, gprims.blackbody_rgb(3000.0), rtol=1e-6)
    assert e[0] > e[2]


# -- instancing -----------------------------------------------------------------------
def _instancer_stage(tmp_path):
    stage = new_stage(tmp_path / "pi.usda")
    pi = UsdGeom.PointInstancer.Define(stage, "/PI")
    pi.AddTranslateOp().Set(Gf.Vec3d(0, 0, 100))
    proto = add_mesh(stage, "/PI/Protos/Tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    proto.AddTranslateOp().Set(Gf.Vec3d(0, 0, 1))   # the prototype root's own transform counts
    pi.CreatePrototypesRel().SetTargets([proto.GetPath()])
    pi.CreateProtoIndicesAttr([0, 0, 0, 0])
    pi.CreatePositionsAttr([Gf.Vec3f(10 * k, 0, 0) for k in range(4)])
    pi.CreateScalesAttr([Gf.Vec3f(1, 1, 1), Gf.Vec3f(2, 2, 2), Gf.Vec3f(1, 1, 1), Gf.Vec3f(1, 1, 1)])
    pi.CreateOrientationsAttr([Gf.Quath(1, 0, 0, 0), Gf.Quath(1, 0, 0, 0),
                               Gf.Quath(math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)), Gf.Quath(1, 0, 0, 0)])
    pi.CreateInvisibleIdsAttr([3])
    return save(stage)


def test_point_instancer_flattened(tmp_path):
    data = translate_stage(_instancer_stage(tmp_path))
    tris = data.positions[data.indices]
    assert len(tris) == 3  # instance 3 is invisible; prototypes render only through the instancer
    expected = [
        [(0, 0, 101), (1, 0, 101), (0, 1, 101)],
        [(10, 0, 102), (12, 0, 102), (10, 2, 102)],      # scaled x2, including the root's translate
        [(20, 0, 101), (20, 1, 101), (19, 0, 101)],      # turned 90 degrees about z
    ]
    np.testing.assert_allclose(tris, expected, atol=1e-3)  # orientations are half floats


def test_point_instancer_as_instances_keeps_one_prototype(tmp_path):
    flat = translate_stage(_instancer_stage(tmp_path))
    inst = translate_stage(_instancer_stage(tmp_path), instancing="instances")
    assert len(inst.indices) == 0 and len(inst.prototypes) == 1
    assert inst.instances.tolist() == [0, 0, 0] and inst.instance_transforms.shape == (3, 4, 4)
    proto = inst.prototypes[0]
    rebuilt = np.concatenate([proto["positions"] @ m[:3, :3] + m[3, :3] for m in inst.instance_transforms])
    np.testing.assert_allclose(rebuilt, flat.positions, atol=1e-5)


def test_native_instances(tmp_path):
    asset = new_stage(tmp_path / "asset.usda")
    root = UsdGeom.Xform.Define(asset, "/Asset")
    add_mesh(asset, "/Asset/Geo", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    asset.SetDefaultPrim(root.GetPrim())
    save(asset)
    stage = new_stage(tmp_path / "scene.usda")
    for k in range(3):
        x = UsdGeom.Xform.Define(stage, f"/I{k}")
        x.AddTranslateOp().Set(Gf.Vec3d(5 * k, 0, 0))
        x.GetPrim().GetReferences().AddReference("./asset.usda")
        x.GetPrim().SetInstanceable(True)
    path = save(stage)
    flat = translate_stage(path)
    assert len(flat.indices) == 3
    np.testing.assert_allclose(sorted(flat.positions[:, 0].max() for _ in [0]), [11.0])
    inst = translate_stage(path, instancing="instances")
    assert len(inst.prototypes) == 1 and len(inst.instances) == 3 and len(inst.indices) == 0
    np.testing.assert_allclose(sorted(inst.instance_transforms[:, 3, 0]), [0, 5, 10])


# -- stage metrics, defaults ------------------------------------------------------------
def test_z_up_default_camera_and_default_lighting_recorded_unapplied(tmp_path):
    stage = new_stage(tmp_path / "z.usda")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    add_mesh(stage, "/M", [(0, 0, 0), (1, 0, 0), (0, 0, 1)], [3], [0, 1, 2])
    path = save(stage)
    data = translate_stage(path)
    # Z-up: the three-quarter view looks from front-right (-Y, +X) and above (+Z).
    fwd = np.array(data.camera.forward)
    assert fwd[1] > 0 and fwd[0] < 0 and fwd[2] < 0 and data.camera.up[2] > 0.8
    assert data.meters_per_unit == 0.01 and data.up_axis == "Z"
    assert data.dome_light is None and any("no lights" in w for w in data.warnings)
    assert data.default_lights["dome"]["radiance"] == [0.5, 0.5, 0.5]
    lit = translate_stage(path, default_light=True)
    assert lit.dome_light["radiance"] == [0.5, 0.5, 0.5] and len(lit.distant_lights) == 1


# -- translate once -----------------------------------------------------------------------
def test_blob_round_trip_keeps_every_field_and_renders_identically(tmp_path):
    import OpenImageIO as oiio
    oiio.ImageBuf(np.full((2, 2, 3), 99, np.uint8)).write(str(tmp_path / "c.png"))
    stage = new_stage(tmp_path / "rt.usda")
    mat = add_material(stage, "/Looks/M", (0.5, 0.5, 0.5))
    tex = UsdShade.Shader.Define(stage, "/Looks/M/T")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./c.png")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface")).GetInput("diffuseColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    m = add_mesh(stage, "/M", *QUAD2, material=mat)
    UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set(
        [Gf.Vec2f(k, k) for k in range(6)])
    light = UsdLux.SphereLight.Define(stage, "/L")
    light.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.5, 3))
    add_render_settings(stage, add_camera(stage, "/Cam", (0.5, 0.5, 4)), (8, 8))
    path = save(stage)
    direct = load_scene(path)
    blob = translate_to_blob(path)
    again = scene_data_from_blob(blob)
    d = direct.data
    for name in ("positions", "indices", "triangle_material", "albedo", "emission", "two_sided_emission",
                 "sphere_lights", "uvs", "distant_lights", "point_lights"):
        np.testing.assert_array_equal(getattr(again, name), getattr(d, name), err_msg=name)
    for k in d.material_params:
        np.testing.assert_array_equal(again.material_params[k], d.material_params[k])
    assert again.camera == d.camera and again.resolution == d.resolution and again.warnings == d.warnings
    assert again.material_textures == d.material_textures
    assert open(again.textures[0]["file"], "rb").read() == (tmp_path / "c.png").read_bytes()
    a = scene_from_blob(blob).render_tile(0, 0, 8, 8, spp=4)
    b = direct.render_tile(0, 0, 8, 8, spp=4)
    assert a.tobytes() == b.tobytes() and a[..., :3].max() > 0


def test_a_corrupt_blob_is_a_scene_error():
    from tessera_renderer import SceneError
    with pytest.raises(SceneError, match="not a Tessera scene blob"):
        scene_from_blob(b"garbage")
    with pytest.raises(SceneError, match="version"):
        scene_from_blob(b"TSSCENE\0" + (99).to_bytes(4, "little") + bytes(8))


def test_udim_textures_are_listed_and_travel_in_the_blob(tmp_path):
    import OpenImageIO as oiio
    for tile, size in ((1001, 4), (1002, 8)):
        oiio.ImageBuf(np.full((size, size, 3), tile % 255, np.uint8)).write(str(tmp_path / f"c.{tile}.png"))
    stage = new_stage(tmp_path / "u.usda")
    mat = add_material(stage, "/Looks/M")
    tex = UsdShade.Shader.Define(stage, "/Looks/M/T")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./c.<UDIM>.png")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/M/Surface")).GetInput("diffuseColor").ConnectToSource(
        tex.ConnectableAPI(), "rgb")
    add_mesh(stage, "/M", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2], mat)
    path = save(stage)
    data = translate_stage(path)
    t = data.textures[0]
    assert t["udim"] and t["file"] == str(tmp_path / "c.<UDIM>.png") and (t["width"], t["height"]) == (8, 8)
    reloaded = scene_data_from_blob(translate_to_blob(path))  # its files live as long as it does
    again = reloaded.textures[0]
    assert sorted(Path(f).name for f in again["udim_files"]) == ["c.1001.png", "c.1002.png"]
    assert Path(again["file"].replace("<UDIM>", "1002")).read_bytes() == (tmp_path / "c.1002.png").read_bytes()


def _lit_floor(tmp_path, name, add_light):
    """A white-ish Lambertian floor (albedo 0.5) seen straight down from y = 1."""
    stage = new_stage(tmp_path / f"{name}.usda")
    # No material, only displayColor: the renderer's pure Lambertian (a UsdPreviewSurface
    # always adds a Fresnel lobe, so it cannot stand for one).
    ground = add_mesh(stage, "/Ground", [(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)], [4], [0, 1, 2, 3])
    ground.CreateDisplayColorAttr([Gf.Vec3f(0.5, 0.5, 0.5)])
    add_light(stage)
    cam = add_camera(stage, "/Cam", (0, 1, 0), focal=1000.0, haperture=1.0, vaperture=1.0)
    cam.AddRotateXOp().Set(-90.0)
    add_render_settings(stage, cam, (4, 4))
    return load_scene(save(stage)).render_tile(0, 0, 4, 4, spp=64, max_depth=1)[..., :3]


@pytest.mark.parametrize("angle,normalize,intensity,irradiance", [
    (0.0, False, math.pi, math.pi),                 # delta sun: intensity is the irradiance
    (10.0, True, math.pi, math.pi),                 # normalize: intensity is the irradiance
    (10.0, False, 2.0, 2.0 * math.pi * math.sin(math.radians(5.0)) ** 2),  # radiance x cone
])
def test_distant_light_irradiance_on_a_lambertian_floor(tmp_path, angle, normalize, intensity, irradiance):
    """Reflected radiance of a Lambertian floor of albedo a under irradiance E is a E / pi."""
    def sun(stage):
        light = UsdLux.DistantLight.Define(stage, "/Sun")
        light.AddRotateXOp().Set(-90.0)   # -Z turned to travel down, along -Y
        light.CreateAngleAttr(angle)
        light.CreateIntensityAttr(intensity)
        light.CreateNormalizeAttr(normalize)
    img = _lit_floor(tmp_path, "sun", sun)
    np.testing.assert_allclose(img, 0.5 * irradiance / math.pi, rtol=1e-3)


def test_point_light_follows_the_inverse_square_law(tmp_path):
    """treatAsPoint + normalize: radiant intensity I = intensity / 4 W/sr, so the floor
    straight below at distance d receives E = I / d^2."""
    def bulb(stage):
        light = UsdLux.SphereLight.Define(stage, "/Bulb")
        light.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
        light.CreateTreatAsPointAttr(True)
        light.CreateNormalizeAttr(True)
        light.CreateIntensityAttr(40.0)
    img = _lit_floor(tmp_path, "bulb", bulb)
    np.testing.assert_allclose(img.mean(), 0.5 / math.pi * (40.0 / 4) / 2.0 ** 2, rtol=1e-3)


def test_rows_say_whether_they_come_from_a_preview_surface(tmp_path):
    stage = new_stage(tmp_path / "ps.usda")
    add_mesh(stage, "/A", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2], add_material(stage, "/Looks/M"))
    add_mesh(stage, "/B", [(0, 0, 1), (1, 0, 1), (0, 1, 1)], [3], [0, 1, 2])
    data = translate_stage(save(stage))
    flags = data.material_params["preview_surface"][data.triangle_material]
    assert flags.tolist() == [1.0, 0.0]
    assert "preview" not in data.material_params  # one flag, under one name
