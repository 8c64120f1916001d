"""The Lambert-only build (CMake TESSERA_LAMBERT_ONLY, renderer/core/feature_set.h): the
baseline of benchmarks/lambert_only.py. Nothing else compiles it, so this test does: it must
render a Lambert-only scene exactly as the full build does (or the benchmark would compare
two different computations), and refuse every other scene by name rather than render it
wrongly."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
BUILD = REPO / "build" / "lambert-only-test"

pytestmark = pytest.mark.slow  # builds a second core (minutes on 2 cores)

CHILD = r"""
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location("tessera_renderer._core", sys.argv[1])
mod = importlib.util.module_from_spec(spec); sys.modules["tessera_renderer._core"] = mod
spec.loader.exec_module(mod)
import hashlib
from dataclasses import replace
import numpy as np
from tessera_renderer import Scene, load_scene
from tessera_renderer.usd.errors import SceneError
from tessera_tools.bench import SCENES, bench_scene_data
out = {}
lambert = Scene(replace(bench_scene_data(SCENES["cornell-lambert"]), uvs=None))
for integ in ("path", "bdpt"):
    splats = np.zeros((24, 24, 3), np.int64) if integ == "bdpt" else None
    img = lambert.render_tile(0, 0, 24, 24, width=24, height=24, spp=4, seed=3, threads=2, integrator=integ,
                              splats=splats)
    img = np.ascontiguousarray(img[0] if isinstance(img, tuple) else img, np.float32)
    out[integ] = hashlib.sha256(img.tobytes() + (b"" if splats is None else splats.tobytes())).hexdigest()
try:
    load_scene(sys.argv[2])
    out["preview"] = "accepted"
except SceneError as e:
    out["preview"] = str(e)
print(json.dumps(out))
"""


def digest(scene, integ: str, seed: int = 3) -> str:
    splats = np.zeros((24, 24, 3), np.int64) if integ == "bdpt" else None
    img = scene.render_tile(0, 0, 24, 24, width=24, height=24, spp=4, seed=seed, threads=2, integrator=integ,
                            splats=splats)
    img = np.ascontiguousarray(img[0] if isinstance(img, tuple) else img, np.float32)
    return hashlib.sha256(img.tobytes() + (b"" if splats is None else splats.tobytes())).hexdigest()


@pytest.fixture(scope="module")
def lambert_core() -> str:
    subprocess.run(["cmake", "-S", str(REPO), "-B", str(BUILD), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
                    "-DTESSERA_BUILD_TESTS=OFF", "-DSKBUILD=ON", f"-DPython_EXECUTABLE={sys.executable}",
                    "-DTESSERA_LAMBERT_ONLY=ON"], check=True, capture_output=True)
    r = subprocess.run(["cmake", "--build", str(BUILD), "--target", "_core", "-j", str(os.cpu_count() or 2)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
    (core,) = (BUILD / "renderer").glob("_core*.so")
    return str(core)


def test_lambert_only_build_renders_the_full_builds_image_and_refuses_the_rest(lambert_core, cornell_path):
    from tessera_renderer import Scene
    from tessera_tools.bench import SCENES, bench_scene_data

    r = subprocess.run([sys.executable, "-c", CHILD, lambert_core, str(cornell_path)], capture_output=True,
                       text=True, cwd=REPO, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    assert r.returncode == 0, r.stderr[-4000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    full = Scene(replace(bench_scene_data(SCENES["cornell-lambert"]), uvs=None))
    for integ in ("path", "bdpt"):
        assert got[integ] == digest(full, integ), f"{integ}: the two builds' images differ"
    # The control: the comparison tells apart the full build's image at another seed.
    assert got["path"] != digest(full, "path", seed=4)
    # The box as authored has UsdPreviewSurface materials: refused, naming the build and the cause.
    assert "TESSERA_LAMBERT_ONLY" in got["preview"] and "UsdPreviewSurface" in got["preview"], got["preview"]

