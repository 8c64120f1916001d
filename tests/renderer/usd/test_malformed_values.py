"""Values of the wrong kind where USD composes them anyway: `float horizontalAperture =
</Path>` and `xformOp:scale = </Path>` open without complaint, and each once raised a bare
TypeError or a USD exception from deep inside the translator (found by the fuzz campaign,
tests/fuzz). Each is refused with a SceneError naming the attribute or the prim."""
from __future__ import annotations

import pytest

from tessera_renderer import SceneError, load_scene

BALL = ('def Sphere "Ball"\n{\n    double3 xformOp:translate = (0, 0, -5)\n'
        '    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n')


def _write(tmp_path, body: str):
    # The shutter is read only at a time code: the stage names a time range.
    path = tmp_path / "bad.usda"
    path.write_text('#usda 1.0\n(\n    startTimeCode = 1\n    endTimeCode = 2\n)\n' + body)
    return path


@pytest.mark.parametrize("attr", ["horizontalAperture", "focalLength", "fStop", "shutter:open"])
def test_a_camera_number_holding_a_path_is_named(tmp_path, attr):
    type_name = "double" if attr.startswith("shutter") else "float"
    path = _write(tmp_path, f'def Camera "Cam"\n{{\n    {type_name} {attr} = </Path>\n}}\n' + BALL)
    with pytest.raises(SceneError, match=rf"/Cam\.{attr}: expected a number, got"):
        load_scene(path)


@pytest.mark.parametrize("attr, value, message", [
    ("float inputs:intensity", "</Path>", r"/Light\.inputs:intensity: expected a number"),
    ("float inputs:exposure", "</Path>", r"/Light\.inputs:exposure: expected a number"),
    ("color3f inputs:color", "</Path>", r"/Light\.inputs:color: expected 3 numbers"),
    ("float inputs:exposure", "1e30", r"/Light: light radiance \[inf, inf, inf\] must be finite"),
])
def test_a_light_value_of_the_wrong_kind_is_named(tmp_path, attr, value, message):
    path = _write(tmp_path, f'def SphereLight "Light"\n{{\n    float inputs:radius = 1\n    {attr} = {value}\n}}\n' + BALL)
    with pytest.raises(SceneError, match=message):
        load_scene(path)


def test_an_xform_op_holding_a_path_is_named(tmp_path):
    path = _write(tmp_path, 'def Sphere "Ball"\n{\n    float3 xformOp:scale = </Path>\n'
                            '    uniform token[] xformOpOrder = ["xformOp:scale"]\n}\n')
    with pytest.raises(SceneError, match=r"/Ball: its transform cannot be evaluated \(.*opVal"):
        load_scene(path)


def test_a_vanishing_fstop_is_refused_and_a_display_color_path_is_noted(tmp_path):
    lens = _write(tmp_path, 'def Camera "Cam"\n{\n    float fStop = 1e-45\n    float focusDistance = 5\n}\n' + BALL)
    with pytest.raises(SceneError, match=r"/Cam: fStop 1.4013e-45 makes the lens infinitely wide"):
        load_scene(lens)
    colour = _write(tmp_path, BALL.replace("{\n", "{\n    color3f[] primvars:displayColor = </Path>\n", 1))
    warnings = load_scene(colour).data.warnings
    assert sum("primvars:displayColor values that are not colours are ignored" in w for w in warnings) == 1
