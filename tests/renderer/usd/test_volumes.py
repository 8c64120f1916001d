"""UsdVol.Volume prims with OpenVDB density fields (usd/volumes.py, docs/media.md): VDB
files made here with OpenVDB's Python module (Debian python3-openvdb), small grids.

- an absorbing VDB slab read through USD (material `anisotropic_vdf`, the prim's
  transform, the VDB's voxel size) in front of an emitter reads Le e^-tau;
- a smoke VDB with the default look renders without warnings, and differs from the
  stage without it;
- fields the core does not render are named in one warning; integrators without media
  support refuse the scene by name."""
from __future__ import annotations

import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tessera import local
from tessera_base.protocol import RenderSettings
from tessera_renderer import SceneError, load_scene

# OpenVDB's Python module (Debian python3-openvdb) is built against the system Python's
# numpy 1.x; the test venv's numpy 2 cannot hand it arrays, so the files are written by
# the system Python in a child process.
_WRITER = textwrap.dedent("""\
    import sys
    import numpy as np
    import pyopenvdb as vdb
    path, voxel, ox, oy, oz, *items = sys.argv[1:]
    grids = []
    for item in items:
        name, npy = item.split("=", 1)
        g = vdb.FloatGrid()
        g.name = name
        g.copyFromArray(np.load(npy).astype(np.float32), ijk=(int(ox), int(oy), int(oz)), tolerance=0)
        g.transform = vdb.createLinearTransform(voxelSize=float(voxel))
        grids.append(g)
    vdb.write(path, grids=grids)
""")
SYSTEM_PYTHON = "/usr/bin/python3"


def write_vdb(path, grids: dict[str, np.ndarray], voxel: float, origin=(0, 0, 0)):
    """A .vdb of float grids (x, y, z) of voxel size `voxel`, active from index `origin`."""
    path = Path(path)
    items = []
    for name, values in grids.items():
        npy = path.with_name(f".{path.stem}.{name}.npy")
        np.save(npy, np.asarray(values, np.float32))
        items.append(f"{name}={npy}")
    proc = subprocess.run([SYSTEM_PYTHON, "-c", _WRITER, str(path), str(voxel), *map(str, origin), *items],
                          capture_output=True, text=True, timeout=120)
    for item in items:
        Path(item.split("=", 1)[1]).unlink()
    assert proc.returncode == 0, proc.stderr


CAMERA = """
def Camera "Camera" {
    float focalLength = 500
    float horizontalAperture = 20
    float verticalAperture = 20
}
"""


def volume_prim(fields: dict[str, str], translate, scale=1.0, material: str | None = None) -> str:
    rels = "\n".join(f"    rel field:{name} = </Vol/{name}>" for name in fields)
    assets = "\n".join(textwrap.dedent(f"""\
        def OpenVDBAsset "{name}" {{
            asset filePath = @./{file}@
            token fieldName = "{name}"
        }}""") for name, file in fields.items())
    binding = f'(prepend apiSchemas = ["MaterialBindingAPI"])' if material else ""
    rel = f"    rel material:binding = <{material}>" if material else ""
    return (f'def Volume "Vol" {binding} {{\n{rels}\n{rel}\n'
            f"    double3 xformOp:translate = {tuple(translate)}\n"
            f"    double3 xformOp:scale = ({scale}, {scale}, {scale})\n"
            '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n'
            + textwrap.indent(assets, "    ") + "\n}\n")


ABSORBER = """
def Material "Absorber" {
    token outputs:mtlx:volume.connect = </Absorber/Vdf.outputs:out>
    def Shader "Vdf" {
        uniform token info:id = "ND_anisotropic_vdf"
        color3f inputs:absorption = (%g, %g, %g)
        color3f inputs:scattering = (0, 0, 0)
        float inputs:anisotropy = 0
        token outputs:out
    }
}
"""

EMITTER = """
def Mesh "Emitter" (prepend apiSchemas = ["MaterialBindingAPI"]) {
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-50, -50, -20), (50, -50, -20), (50, 50, -20), (-50, 50, -20)]
    rel material:binding = </Glow>
}
def Material "Glow" {
    token outputs:surface.connect = </Glow/S.outputs:surface>
    def Shader "S" {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor = (0, 0, 0)
        color3f inputs:emissiveColor = (1, 2, 0.5)
        token outputs:surface
    }
}
"""


def render(scene, spp=16, seed=1, size=8, integrator="path"):
    settings = RenderSettings(width=size, height=size, spp=spp, seed=seed, tile_size=size, integrator=integrator)
    return local.render_image(scene, settings, progress=False, variance=False).rgba


# A constant density D in 10 x 10 x 4 voxels of size 0.5 (scaled x 2 by the prim: world
# voxels of 1, the slab 4 thick), absorption colour a per unit density: tau = a D 4 per
# channel. A constant grid is tracked exactly, so every pixel reads Le e^-tau within 1 %;
# 2 % detected: the closed form at tau + ln 1.02 is outside the band (negative control).
@pytest.mark.parametrize("tau", [0.1, 1.0, 3.0])
def test_absorbing_vdb_slab_through_usd_reads_beer_lambert(tmp_path, tau):
    density = 0.5
    absorption = np.array([1.0, 0.5, 2.0]) * tau / (density * 4)
    write_vdb(tmp_path / "slab.vdb", {"density": np.full((10, 10, 4), density)}, 0.5, origin=(-5, -5, -2))
    (tmp_path / "slab.usda").write_text("#usda 1.0\n" + CAMERA + EMITTER + ABSORBER % tuple(absorption)
                                        + volume_prim({"density": "slab.vdb"}, (0, 0, -10), 2.0, "/Absorber"))
    scene = load_scene(tmp_path / "slab.usda")
    assert scene.warnings == [], scene.warnings
    pixels = render(scene, spp=4)[..., :3].reshape(-1, 3)
    want = np.array([1.0, 2.0, 0.5]) * np.exp(-np.array([1.0, 0.5, 2.0]) * tau)
    assert np.allclose(pixels, want, rtol=0.01), (pixels.min(axis=0), pixels.max(axis=0), want)
    assert not np.allclose(pixels, want / 1.02, rtol=0.01), "negative control"


def smoke_grid(n=24) -> np.ndarray:
    x = (np.arange(n) + 0.5) / n * 2 - 1
    r2 = x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2
    return np.clip(1 - r2, 0, None) * 3.0  # a soft ball, density 3 at its centre


LIGHTS = """
def DistantLight "Sun" {
    float inputs:intensity = 3
    float3 xformOp:rotateXYZ = (-45, 30, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
}
def DomeLight "Sky" {
    float inputs:intensity = 0.3
}
"""


def test_smoke_vdb_renders_without_warnings(tmp_path):
    write_vdb(tmp_path / "smoke.vdb", {"density": smoke_grid()}, 0.1, origin=(-12, -12, -12))
    camera = CAMERA.replace("float focalLength = 500", "float focalLength = 50")
    (tmp_path / "smoke.usda").write_text("#usda 1.0\n" + camera + LIGHTS
                                         + volume_prim({"density": "smoke.vdb"}, (0, 0, -10)))
    scene = load_scene(tmp_path / "smoke.usda")
    assert scene.warnings == [], scene.warnings
    img = render(scene, spp=8, size=16)
    assert np.isfinite(img).all()
    (tmp_path / "empty.usda").write_text("#usda 1.0\n" + camera + LIGHTS)
    sky = render(load_scene(tmp_path / "empty.usda"), spp=8, size=16)
    centre, corner = (slice(6, 10), slice(6, 10)), (slice(0, 2), slice(0, 2))
    # The smoke is seen in the middle (it scatters the sun and hides the sky), not in the corners.
    assert np.abs(img[centre][..., :3] - sky[centre][..., :3]).mean() > 0.05 * sky[centre][..., :3].mean()
    assert np.allclose(img[corner][..., :3], sky[corner][..., :3], rtol=1e-5)
    with pytest.raises(Exception, match="participating media"):
        render(scene, spp=1, size=8, integrator="bdpt")
    # light renders homogeneous media (absorbing glass) but not grid media: it says so too.
    with pytest.raises(Exception, match="grid media"):
        render(scene, spp=1, size=8, integrator="light")
    from tessera.pilot import run_pilot  # auto measures no candidate that would refuse the scene
    assert run_pilot(scene, RenderSettings(width=16, height=16, spp=1, integrator="auto")).choice == "path"


def test_fields_not_rendered_are_named_in_one_warning(tmp_path):
    grid = smoke_grid(8)
    write_vdb(tmp_path / "pyro.vdb", {"density": grid, "temperature": grid, "Cd": grid}, 0.25)
    (tmp_path / "pyro.usda").write_text(
        "#usda 1.0\n" + CAMERA + LIGHTS
        + volume_prim({"density": "pyro.vdb", "temperature": "pyro.vdb", "Cd": "pyro.vdb"}, (0, 0, -10)))
    warnings = load_scene(tmp_path / "pyro.usda").warnings
    assert len(warnings) == 1, warnings
    assert "temperature" in warnings[0] and "Cd" in warnings[0] and "not rendered" in warnings[0], warnings


def test_missing_or_escaping_vdb_files_are_reported(tmp_path):
    (tmp_path / "missing.usda").write_text("#usda 1.0\n" + CAMERA + LIGHTS
                                           + volume_prim({"density": "nothere.vdb"}, (0, 0, -10)))
    warnings = load_scene(tmp_path / "missing.usda").warnings
    assert any("nothere.vdb" in w and "missing" in w for w in warnings), warnings
    (tmp_path / "inner").mkdir()
    write_vdb(tmp_path / "outside.vdb", {"density": smoke_grid(4)}, 0.25)
    (tmp_path / "inner" / "escape.usda").write_text(
        "#usda 1.0\n" + CAMERA + LIGHTS + volume_prim({"density": "../outside.vdb"}, (0, 0, -10)))
    with pytest.raises(SceneError):
        load_scene(tmp_path / "inner" / "escape.usda")
