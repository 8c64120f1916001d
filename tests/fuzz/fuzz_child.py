"""The fuzz campaigns of test_fuzz.py, run in a child process so that a crash (segfault,
abort) of the renderer or of USD is a test failure with its input, not the end of pytest.

    python fuzz_child.py {scene,usd} WORKDIR MAX_EXAMPLES

Before each example it writes the input to WORKDIR/current (what the parent shows if the
process dies); an input that raises anything but the allowed, clear exceptions fails the
Hypothesis run, which prints the shrunk example and exits 1. On success it writes a JSON
summary of the outcomes to WORKDIR/summary.json.
"""
from __future__ import annotations

import collections
import json
import sys
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tessera_renderer import NonFiniteSampleError, Scene, SceneError, _core, load_scene
from tessera_renderer.usd import CameraDesc, SceneData

WORK = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(".")
outcomes: collections.Counter = collections.Counter()


def record(text: str) -> None:
    (WORK / "current").write_text(text)


def fuzz_settings(n: int):
    return settings(max_examples=n, deadline=None, database=None, derandomize=True,
                    suppress_health_check=list(HealthCheck), print_blob=True)


# ------------------------------------------------------------------ scene arrays
FLOATS = st.one_of(st.floats(-10, 10, width=32), st.sampled_from([0.0, -0.0, 1e-38, 1e30, -1e30, 3.4e38]),
                   st.floats(width=32))  # the last includes NaN and +-Inf


def float_rows(columns: int, max_rows: int = 6):
    return st.integers(0, max_rows).flatmap(
        lambda n: hnp.arrays(np.float32, (n, columns), elements=FLOATS))


@st.composite
def scene_arrays(draw):
    """Arrays for _core.Scene: mostly plausible, often broken in one or more ways."""
    v = draw(st.integers(0, 8))
    t = draw(st.integers(0, 6))
    m = draw(st.integers(0, 3))
    positions = draw(hnp.arrays(np.float32, (v, 3), elements=FLOATS))
    index_max = draw(st.sampled_from([max(v - 1, 0), v, v + 3, 2 ** 32 - 1]))
    indices = draw(hnp.arrays(np.uint32, (t, 3), elements=st.integers(0, index_max)))
    tri_len = draw(st.sampled_from([t, t, t + 1, max(t - 1, 0)]))
    triangle_material = draw(hnp.arrays(np.uint32, (tri_len,), elements=st.integers(0, m + 2)))
    albedo = draw(hnp.arrays(np.float32, (m, 3), elements=FLOATS))
    emission = draw(hnp.arrays(np.float32, (draw(st.sampled_from([m, m, m + 1])), 3), elements=FLOATS))
    two_sided = draw(hnp.arrays(np.bool_, (m,)))
    arrays = dict(positions=positions, indices=indices, triangle_material=triangle_material, albedo=albedo,
                  emission=emission, two_sided_emission=two_sided, sphere_lights=draw(float_rows(7, 2)),
                  point_lights=draw(float_rows(6, 2)), distant_lights=draw(float_rows(7, 2)),
                  dome_radiance=tuple(draw(st.lists(FLOATS, min_size=3, max_size=3))))
    # Sometimes the wrong shape, dtype or layout for one array.
    mangle = draw(st.sampled_from([None, None, "shape", "dtype", "order", "ndim", "signed"]))
    if mangle:
        key = draw(st.sampled_from(["positions", "indices", "triangle_material", "albedo", "sphere_lights"]))
        a = arrays[key]
        if mangle == "shape":
            arrays[key] = np.zeros((a.shape[0], 2) if a.ndim == 2 else (a.shape[0], 2), a.dtype)
        elif mangle == "dtype":
            arrays[key] = a.astype(np.float64 if a.dtype == np.float32 else np.int64)
        elif mangle == "order" and a.ndim == 2 and a.shape[0] > 1:
            arrays[key] = np.asfortranarray(np.repeat(a, 2, axis=1))[:, ::2]
        elif mangle == "ndim":
            arrays[key] = a.reshape(-1)
        elif mangle == "signed":
            arrays[key] = -np.ones(a.shape, np.int64)
    return arrays


def scene_campaign(n: int) -> None:
    camera = _core.Camera((0, 0, 2), (1, 0, 0), (0, 1, 0), (0, 0, -1), 0.5, 0.5, 4, 4)

    @given(scene_arrays())
    @fuzz_settings(n)
    def fuzz(arrays):
        record(repr(arrays))
        try:
            scene = _core.Scene(**arrays)
        except (ValueError, TypeError) as exc:  # ValueError: the core's checks; TypeError: the binding's
            assert str(exc), "an exception without a message"
            outcomes[f"refused: {type(exc).__name__}"] += 1
            return
        outcomes["built"] += 1
        for info in _core.integrators():
            integrator = info["name"]
            splats = np.zeros((4, 4, 3), np.int64)
            # A scene-pass integrator renders from its product: a small one, fuzzed alike.
            params = {"photons": 64.0} if "photons" in info["params"] else {}
            product = None
            if info["scene_passes"]:
                try:
                    product = _core.scene_pass(scene, integrator, 0, 0, 8, 1, params)
                except ValueError as exc:  # a setting the scene cannot take (too many elements): named
                    assert str(exc), "an exception without a message"
                    outcomes[f"scene pass refused: {integrator}"] += 1
                    continue
            rgba, stats = _core.render_tile(scene, camera, 0, 0, 4, 4, 2, 0, 8, 1, 0, True, integrator, splats,
                                            integrator_params=params, scene_product=product)
            assert np.isfinite(rgba).all() or stats["nonfinite_samples"], "NaN pixels the counter missed"
            outcomes[f"rendered: {'nonfinite counted' if stats['nonfinite_samples'] else 'finite'}"] += 1

    fuzz()


def wrapper_campaign(n: int) -> None:
    """The public wrapper (tessera_renderer.Scene over SceneData): SceneError or TypeError."""
    @given(scene_arrays())
    @fuzz_settings(n)
    def fuzz(arrays):
        record(repr(arrays))
        cam = CameraDesc((0, 0, 2), (1, 0, 0), (0, 1, 0), (0, 0, -1), 1.0, 1.0, 1.0, "fuzz")
        data = SceneData(positions=arrays["positions"], indices=arrays["indices"],
                         triangle_material=arrays["triangle_material"], albedo=arrays["albedo"],
                         emission=arrays["emission"], two_sided_emission=arrays["two_sided_emission"],
                         sphere_lights=arrays["sphere_lights"], camera=cam, resolution=(4, 4),
                         resolution_from_stage=True, point_lights=arrays["point_lights"],
                         distant_lights=arrays["distant_lights"])
        try:
            scene = Scene(data)
        except SceneError as exc:
            assert str(exc)
            outcomes["refused: SceneError"] += 1
            return
        except TypeError as exc:
            assert "incompatible function arguments" in str(exc), exc
            outcomes["refused: TypeError"] += 1
            return
        try:
            scene.render_tile(0, 0, 4, 4, spp=2, threads=1)
            outcomes["rendered"] += 1
        except NonFiniteSampleError:
            outcomes["rendered: NonFiniteSampleError"] += 1

    fuzz()


# ------------------------------------------------------------------ USD
BASE_USDA = """#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = {mpu}
)

def Mesh "Mesh"
{{
    int[] faceVertexCounts = {counts}
    int[] faceVertexIndices = {indices}
    point3f[] points = {points}
    {normals}
    uniform token subdivisionScheme = "none"
    color3f[] primvars:displayColor = {color}
    uniform token orientation = {orientation}
}}

def Sphere "Ball"
{{
    double radius = {radius}
    double3 xformOp:translate = {translate}
    float3 xformOp:scale = {scale}
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
}}

def {light_type} "Light"
{{
    float inputs:intensity = {intensity}
    float inputs:exposure = {exposure}
    color3f inputs:color = {color1}
    float inputs:radius = {radius2}
    float inputs:width = {width}
    float inputs:height = {height}
    float inputs:angle = {angle}
    double3 xformOp:translate = {translate2}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}

def Camera "Cam"
{{
    float focalLength = {focal}
    float horizontalAperture = {aperture}
    float verticalAperture = {aperture2}
    float fStop = {fstop}
    float focusDistance = {focus}
    float2 clippingRange = ({near}, {far})
    double3 xformOp:translate = (0, 0, 5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""

NUMBER = st.one_of(st.floats(-100, 100).map(lambda x: f"{x:.6g}"),
                   st.sampled_from(["0", "-1", "1e30", "-1e30", "1e300", "nan", "inf", "-inf", "1e-45"]))
WRONG = st.sampled_from(['"text"', "(1, 2)", "[1, 2, 3]", "", "@a.usda@", "</Path>", "true", "None"])


def value(scalar=NUMBER):
    return st.one_of(scalar, scalar, scalar, WRONG)


def vec3():
    return st.one_of(st.tuples(NUMBER, NUMBER, NUMBER).map(lambda t: "(" + ", ".join(t) + ")"), WRONG)


def array_of(item, max_size=12):
    return st.one_of(st.lists(item, max_size=max_size).map(lambda xs: "[" + ", ".join(xs) + "]"), WRONG)


VALID = dict(mpu="0.01", counts="[4]", indices="[0, 1, 2, 3]",
             points="[(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]", color="[(0.5, 0.5, 0.5)]", normals="",
             orientation='"rightHanded"', radius="0.5", translate="(0, 0, 1)", scale="(1, 1, 1)",
             light_type="SphereLight", intensity="10", exposure="0", color1="(1, 1, 1)", radius2="0.2",
             width="1", height="1", angle="1", translate2="(0, 1, 3)", focal="50", aperture="36",
             aperture2="24", fstop="0", focus="5", near="0.1", far="1000")


@st.composite
def usda_text(draw):
    """A valid scene (a lit quad and a sphere seen by a camera) with a few of its fields
    replaced by random, out-of-range or wrongly typed values, sometimes then garbled."""
    random_fields = dict(
        mpu=value(), counts=array_of(st.sampled_from(["3", "4", "0", "-1", "2", "1000000", "2147483647"])),
        indices=array_of(st.sampled_from(["0", "1", "2", "3", "-1", "7", "4294967295", "99999999"])),
        points=array_of(vec3(), 8), color=array_of(vec3(), 3),
        normals=st.sampled_from(["normal3f[] normals = [(0, 0, 1)]",
                                 'normal3f[] primvars:normals = [(nan, 0, 1), (0, 0, 0)] (interpolation = "faceVarying")',
                                 "int[] primvars:normals:indices = [5, -2]"]),
        orientation=st.sampled_from(['"leftHanded"', '"sideways"', "1"]),
        radius=value(), translate=vec3(), scale=vec3(),
        light_type=st.sampled_from(["RectLight", "DiskLight", "DistantLight", "DomeLight", "CylinderLight",
                                    "Xform", "Mesh"]),
        intensity=value(), exposure=value(), color1=vec3(), radius2=value(), width=value(), height=value(),
        angle=value(), translate2=vec3(), focal=value(), aperture=value(), aperture2=value(), fstop=value(),
        focus=value(), near=NUMBER, far=NUMBER)
    changed = draw(st.lists(st.sampled_from(sorted(random_fields)), min_size=0, max_size=4, unique=True))
    fields = dict(VALID)
    for key in changed:
        fields[key] = draw(random_fields[key])
    text = BASE_USDA.format(**fields).encode()
    # Sometimes garbage: bytes flipped, cut short, or junk inserted.
    mutation = draw(st.sampled_from([None, None, None, "flip", "truncate", "insert", "binary"]))
    if mutation == "flip":
        for pos in draw(st.lists(st.integers(0, len(text) - 1), min_size=1, max_size=8)):
            text = text[:pos] + bytes([text[pos] ^ draw(st.integers(1, 255))]) + text[pos + 1:]
    elif mutation == "truncate":
        text = text[:draw(st.integers(0, len(text)))]
    elif mutation == "insert":
        pos = draw(st.integers(0, len(text)))
        text = text[:pos] + draw(st.binary(min_size=1, max_size=40)) + text[pos:]
    elif mutation == "binary":
        text = b"PXR-USDC" + draw(st.binary(max_size=200))
    return text


def usd_campaign(n: int) -> None:
    @given(usda_text(), st.sampled_from([".usda", ".usd", ".usdc"]))
    @fuzz_settings(n)
    def fuzz(text, suffix):
        path = WORK / f"fuzz{suffix}"
        path.write_bytes(text)
        record(f"{suffix}\n{text!r}")
        try:
            scene = load_scene(path)
        except SceneError as exc:
            assert str(exc)
            outcomes["refused: SceneError"] += 1
            return
        outcomes["loaded"] += 1
        try:
            rgba = scene.render_tile(0, 0, 4, 4, width=4, height=4, spp=2, threads=1)
        except NonFiniteSampleError:
            outcomes["rendered: NonFiniteSampleError"] += 1
            return
        assert np.isfinite(rgba).all()
        outcomes["rendered"] += 1

    fuzz()


if __name__ == "__main__":
    campaign, n = sys.argv[1], int(sys.argv[3])
    {"scene": scene_campaign, "wrapper": wrapper_campaign, "usd": usd_campaign}[campaign](n)
    (WORK / "summary.json").write_text(json.dumps(dict(outcomes)))
