"""Subdivision surfaces (issue 11 item 6): the translator refines catmullClark and loop
meshes with OpenSubdiv onto their limit surface. Expected values are closed forms from the
subdivision literature, computed here from the cage, never from the refiner:

- Catmull-Clark limit of a vertex of valence n in an all-quad mesh (Halstead, Kass and
  DeRose 1993): (n^2 v + 4 sum(edge neighbours) + sum(diagonal neighbours)) / (n (n + 5)).
- Loop limit of a vertex of valence n (Loop 1987): (1 - n w) v + w sum(neighbours) with
  w = 1 / (n + 3 / (8 beta)), beta = (5/8 - (3/8 + cos(2 pi / n) / 4)^2) / n.

Each check is also run on the control cage (subdivision level 0), which must fail it."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_SCENES
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from tessera_renderer.usd import SceneError, translate_opened_stage, translate_stage

SCENES = SHARED_SCENES

# A cube [-1, 1]^3, faces wound counter-clockwise seen from outside.
CUBE_POINTS = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1),
               (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
CUBE_FACES = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (1, 2, 6, 5), (0, 4, 7, 3)]
CUBE_EDGES = sorted({tuple(sorted((f[i], f[(i + 1) % 4]))) for f in CUBE_FACES for i in range(4)})
# An octahedron: every vertex has valence 4 (Loop's irregular case for a triangle mesh).
OCTA_POINTS = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
OCTA_FACES = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]

# Positions are float32 in the core: 1e-4 is ~100 ulps at radius 1; the cage misses the
# corner limit by 0.87 and the refined-but-not-limit level-3 vertex by ~0.01.
POS_TOL = 1e-4


def _stage(points, faces, scheme="catmullClark", left=False, **attrs):
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    mesh = UsdGeom.Mesh.Define(stage, "/M")
    if left:
        faces = [tuple(reversed(f)) for f in faces]
        mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in points])
    mesh.CreateFaceVertexCountsAttr([len(f) for f in faces])
    mesh.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    mesh.CreateSubdivisionSchemeAttr(scheme)
    for name, value in attrs.items():
        mesh.GetPrim().GetAttribute(name).Set(value)
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 8))
    return stage, mesh


def _translate(stage, level):
    data = translate_opened_stage(stage, 0, subdivision_level=level, camera_relative=False)
    used = np.unique(data.indices)
    return data, data.positions[used].astype(np.float64)


def _nearest(points, direction):
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return points[np.argmax(points @ d)]  # the surfaces here are convex: the extreme vertex


def _catmull_clark_corner_limit():
    v = np.array(CUBE_POINTS[6], float)  # (1, 1, 1), valence 3
    edge = [np.array(CUBE_POINTS[j], float) for e in CUBE_EDGES if 6 in e for j in e if j != 6]
    diag = [np.array(CUBE_POINTS[f[(f.index(6) + 2) % 4]], float) for f in CUBE_FACES if 6 in f]
    n = len(edge)
    return (n * n * v + 4 * sum(edge) + sum(diag)) / (n * (n + 5))


def _loop_limit_octa_vertex():
    n = 4
    beta = (5 / 8 - (3 / 8 + math.cos(2 * math.pi / n) / 4) ** 2) / n
    w = 1 / (n + 3 / (8 * beta))
    v = np.array(OCTA_POINTS[4], float)
    ring = sum(np.array(OCTA_POINTS[j], float) for j in range(4))
    return (1 - n * w) * v + w * ring


def test_catmull_clark_cube_corner_is_on_the_limit_surface_and_the_cage_is_not():
    expected = _catmull_clark_corner_limit()
    assert np.allclose(expected, 0.5)  # the literature's value for this cube
    for level in (1, 3):
        stage, _ = _stage(CUBE_POINTS, CUBE_FACES)
        data, pts = _translate(stage, level)
        assert len(data.indices) == 6 * 4 ** level * 2
        corner = _nearest(pts, (1, 1, 1))
        assert np.linalg.norm(corner - expected) < POS_TOL, (level, corner)
        assert not any("subdivision" in w for w in data.warnings), data.warnings
    # Negative control: the cage (level 0) keeps the corner at (1, 1, 1).
    stage, _ = _stage(CUBE_POINTS, CUBE_FACES)
    data, pts = _translate(stage, 0)
    assert np.linalg.norm(_nearest(pts, (1, 1, 1)) - expected) > 100 * POS_TOL
    assert any("control cage" in w for w in data.warnings)


@pytest.mark.parametrize("left", [False, True])
def test_limit_normals_point_outwards_along_the_symmetry_axes(left):
    stage, _ = _stage(CUBE_POINTS, CUBE_FACES, left=left)
    data = translate_opened_stage(stage, 0, subdivision_level=2, camera_relative=False)
    corners = data.positions[data.indices]          # (T, 3, 3)
    normals = data.shading_normals                   # (T, 3, 3)
    at = np.linalg.norm(corners - 0.5, axis=2) < 1e-4  # triangle corners at the (1,1,1) limit
    assert at.any()
    # By symmetry the limit normal at the cube's corner is (1, 1, 1) / sqrt 3.
    assert np.allclose(normals[at], 1 / math.sqrt(3), atol=1e-4)
    # Geometric winding agrees with the shading normals everywhere (outward).
    geo = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(np.einsum("ij,ij->i", geo, normals.mean(axis=1)) > 0)


def test_infinitely_sharp_creases_keep_the_cube_and_smooth_edges_do_not():
    edges = Vt.IntArray([i for e in CUBE_EDGES for i in e])
    stage, mesh = _stage(CUBE_POINTS, CUBE_FACES)
    mesh.CreateCreaseIndicesAttr(edges)
    mesh.CreateCreaseLengthsAttr([2] * len(CUBE_EDGES))
    mesh.CreateCreaseSharpnessesAttr([10.0] * len(CUBE_EDGES))  # 10: infinitely sharp
    _, pts = _translate(stage, 3)
    on_cube = np.abs(np.abs(pts).max(axis=1) - 1.0)
    assert on_cube.max() < POS_TOL
    assert np.linalg.norm(_nearest(pts, (1, 1, 1)) - 1.0) < POS_TOL
    # Control: without creases the surface leaves the cube by far more than the tolerance.
    stage, _ = _stage(CUBE_POINTS, CUBE_FACES)
    _, pts = _translate(stage, 3)
    assert np.abs(np.abs(pts).max(axis=1) - 1.0).max() > 0.1


def test_a_sharp_corner_stays_on_its_cage_vertex_the_others_move():
    stage, mesh = _stage(CUBE_POINTS, CUBE_FACES)
    mesh.CreateCornerIndicesAttr([6])
    mesh.CreateCornerSharpnessesAttr([10.0])
    _, pts = _translate(stage, 3)
    assert np.linalg.norm(_nearest(pts, (1, 1, 1)) - 1.0) < POS_TOL
    # The opposite corner is smooth: on the Catmull-Clark limit.
    assert np.linalg.norm(_nearest(pts, (-1, -1, -1)) + _catmull_clark_corner_limit()) < POS_TOL


def test_loop_octahedron_vertex_is_on_loop_limit_and_the_cage_is_not():
    expected = _loop_limit_octa_vertex()
    stage, _ = _stage(OCTA_POINTS, OCTA_FACES, scheme="loop")
    data, pts = _translate(stage, 3)
    assert len(data.indices) == 8 * 4 ** 3
    top = _nearest(pts, (0, 0, 1))
    assert np.linalg.norm(top - expected) < POS_TOL, (top, expected)
    stage, _ = _stage(OCTA_POINTS, OCTA_FACES, scheme="loop")
    _, pts = _translate(stage, 0)
    assert np.linalg.norm(_nearest(pts, (0, 0, 1)) - expected) > 100 * POS_TOL
    # Control: Catmull-Clark's rules on the same triangles give another surface.
    stage, _ = _stage(OCTA_POINTS, OCTA_FACES, scheme="catmullClark")
    _, pts = _translate(stage, 3)
    assert np.linalg.norm(_nearest(pts, (0, 0, 1)) - expected) > 100 * POS_TOL


def test_holes_drop_their_refined_faces():
    stage, mesh = _stage(CUBE_POINTS, CUBE_FACES)
    mesh.CreateHoleIndicesAttr([1])  # the +z face
    data, pts = _translate(stage, 2)
    assert len(data.indices) == 5 * 4 ** 2 * 2
    assert pts[:, 2].max() < 1.0  # nothing of the +z face's interior is left at its centre
    centres = data.positions[data.indices].mean(axis=1)
    assert not np.any((np.abs(centres[:, 0]) < 0.3) & (np.abs(centres[:, 1]) < 0.3) & (centres[:, 2] > 0))


def test_face_varying_uvs_are_bilinear_inside_each_cage_face():
    # One quad with st (0,0) (1,0) (1,1) (0,1) at its corners: the refined corner at the
    # face's centre must carry st (0.5, 0.5), and every st the bilinear map of its position.
    stage, mesh = _stage([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
    pv.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    data = translate_opened_stage(stage, 0, subdivision_level=2, camera_relative=False)
    assert data.uvs is not None and len(data.uvs) == 32
    centre = np.linalg.norm(data.positions[data.indices][..., :2] - 0.5, axis=2) < 1e-5
    assert centre.any()
    assert np.allclose(data.uvs[centre], 0.5, atol=1e-5)
    # On this flat unit square with boundary corners pinned, the limit surface is the
    # square itself, so the bilinear st of each corner equals its (x, y).
    xy = data.positions[data.indices][..., :2]
    assert np.allclose(data.uvs, xy, atol=1e-5)
    # Control: st mirrored in x fails the same check.
    assert not np.allclose(data.uvs, np.stack([1 - xy[..., 0], xy[..., 1]], -1), atol=0.1)


def test_level_is_validated():
    stage, _ = _stage(CUBE_POINTS, CUBE_FACES)
    with pytest.raises(SceneError, match="subdivision level"):
        translate_opened_stage(stage, 0, subdivision_level=-1)


@pytest.mark.shared_scenes
def test_shared_pyramids_render_subdivided_without_a_warning():
    path = SCENES / "usdwg_subdiv_pyramids" / "Creases_SpinningPyramids.usda"
    data = translate_stage(str(path), 0)
    assert len(data.indices) > 144 * 8  # the cage has 144 triangles
    assert not any("subdivision" in w or "cage" in w for w in data.warnings), data.warnings
    cage = translate_stage(str(path), 0, subdivision_level=0)
    assert len(cage.indices) == 144


def test_too_many_refined_triangles_name_the_subdivision_level():
    from tessera_renderer.usd.bundle import Limits

    limits = Limits(triangles=200)  # each mesh may have a quarter: 50 triangles
    # One cube: level 3 (768 triangles) is lowered to level 1 (48), with a note.
    stage, _ = _stage(CUBE_POINTS, CUBE_FACES)
    data = translate_opened_stage(stage, 0, subdivision_level=3, limits=limits)
    assert len(data.indices) == 48
    assert any("refined to level 1 instead of 3" in w for w in data.warnings)
    # Eight such cubes pass the scene's limit: the error says that subdivision made them.
    for k in range(1, 8):
        UsdGeom.Mesh.Define(stage, f"/M{k}").GetPrim().GetReferences().AddInternalReference("/M")
    with pytest.raises(SceneError, match="lower subdivision level"):
        translate_opened_stage(stage, 0, subdivision_level=1, limits=limits)
    # Control: the cages (12 triangles each) fit, and their error-free run has no such note.
    data = translate_opened_stage(stage, 0, subdivision_level=0, limits=limits)
    assert len(data.indices) == 8 * 12
