"""Per-user limits on what a scene may cost the farm, at pre-flight (issue 42, item 13: an
82 KB .usdc declaring 10^7 triangles was accepted and cost the farm 9 GB). Real uvicorn
API with three users' tokens, real inspection processes, redis-server: a small .usdc
declaring more triangles than a user's limit is refused from its face counts, naming the
limit and its setting; a user allowed more triangles but a smaller translated size is
refused by that; a user allowed both gets the job."""
from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from conftest import start_api
from test_preflight_limits import write_mesh

DECLARED = 400_000                  # triangles the file declares (200,000 quads)
DEFAULT_TRIANGLES = DECLARED - 1    # every user's limit: one triangle short
# The translated scene holds at least its triangle indices (3 x 4 bytes a triangle,
# 4.8 MB here): a limit of 1 MB is well under it, 1 GB well over it.
SMALL_TRANSLATED, LARGE_TRANSLATED = 1 << 20, 1 << 30


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(
        redis_server, tmp_path_factory.mktemp("api"),
        api_tokens="alice:alice-token,bob:bob-token,carol:carol-token",
        user_max_triangles=str(DEFAULT_TRIANGLES),
        user_limits=f"bob:triangles={DECLARED}:translated={SMALL_TRANSLATED},"
                    f"carol:triangles={DECLARED}:translated={LARGE_TRANSLATED}")
    with httpx.Client(base_url=base, timeout=120) as client:
        yield client
    proc.stop()


@pytest.fixture(scope="module")
def declares(tmp_path_factory) -> Path:
    path = write_mesh(tmp_path_factory.mktemp("scene") / "declares.usdc", DECLARED, sides=4)
    assert path.stat().st_size < 100_000  # a small file that declares many triangles
    return path


def _submit(api, scene: Path, token: str) -> httpx.Response:
    return api.post("/jobs", files={"file": (scene.name, scene.read_bytes())},
                    data={"width": "16", "height": "16", "spp": "1"},
                    headers={"Authorization": f"Bearer {token}"})


def test_a_scene_over_a_users_triangle_limit_is_refused_naming_the_setting(api, declares):
    r = _submit(api, declares, "alice-token")
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert f"more than {DEFAULT_TRIANGLES} triangles" in detail
    assert "TESSERA_USER_MAX_TRIANGLES" in detail
    # The remembered refusal (the same file again) names it too.
    again = _submit(api, declares, "alice-token")
    assert again.status_code == 422 and "TESSERA_USER_MAX_TRIANGLES" in again.json()["detail"]


def test_the_translated_size_limit_refuses_what_the_triangle_limit_lets_through(api, declares):
    r = _submit(api, declares, "bob-token")
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "TESSERA_USER_MAX_TRANSLATED_BYTES" in detail and f"({SMALL_TRANSLATED} bytes)" in detail, detail
    # Carol may have both: the same file (its remembered inspection) becomes a job.
    r = _submit(api, declares, "carol-token")
    assert r.status_code == 201, r.text


def test_the_issues_file_is_refused_under_the_default_limits(redis_server, tmp_path):
    """The issue's case with no limit configured: a small .usdc declaring 10^7 triangles
    (was accepted, 520 MB translated, 9 GB of farm RSS) is refused from its face counts by
    the default per-user limit (4,000,000), which its message names."""
    path = write_mesh(tmp_path / "ten_million.usdc", 10_000_000, sides=4)
    assert path.stat().st_size < 100_000
    (tmp_path / "api").mkdir()
    proc, base = start_api(redis_server, tmp_path / "api", api_tokens="dave:dave-token")
    try:
        with httpx.Client(base_url=base, timeout=120) as client:
            r = _submit(client, path, "dave-token")
    finally:
        proc.stop()
    assert r.status_code == 422, r.text
    assert "limit of 4000000 triangles" in r.json()["detail"]  # 5 M faces: the mesh alone is over it
    assert "TESSERA_USER_MAX_TRIANGLES" in r.json()["detail"]


def _row_of_cage_quads(path, camera_distance: float):
    """400 Catmull-Clark quads 0.05 wide in a row along x, a camera on +z at the distance."""
    from pxr import Usd, UsdGeom, Vt
    import numpy as np

    stage = Usd.Stage.CreateNew(str(path))
    camera = UsdGeom.Camera.Define(stage, "/Cam")
    camera.AddTranslateOp().Set((0.0, 0.0, camera_distance))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Cage")
    n = 400
    xs = np.arange(n + 1, dtype=np.float32)
    points = np.concatenate([np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], -1),
                             np.stack([xs, np.ones_like(xs), np.zeros_like(xs)], -1)]) * 0.05
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(n, 4, np.int32)))
    k = np.arange(n, dtype=np.int32)
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.stack([k, k + 1, k + n + 2, k + n + 1], -1).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.catmullClark)
    stage.GetRootLayer().Save()
    return path

def test_a_higher_subdivision_level_is_held_to_the_translated_size_limit(api, tmp_path):
    """The job's subdivision level multiplies what its subdivision surfaces cost (x16 per
    two levels): the pre-flight translates at that level. 400 Catmull-Clark quads are
    12,800 triangles at the default level 2 (about 0.75 MB translated, within Bob's 1 MiB);
    at level 4, 204,800 triangles (about 12 MB), over it. Before, the level-2 verdict let
    the level-4 job through."""
    path = _row_of_cage_quads(tmp_path / "cage.usdc", camera_distance=60.0)

    def submit(level: str | None) -> httpx.Response:
        data = {"width": "16", "height": "16", "spp": "1", **({"subdivision_level": level} if level else {})}
        return api.post("/jobs", files={"file": (path.name, path.read_bytes())}, data=data,
                        headers={"Authorization": "Bearer bob-token"})

    assert submit(None).status_code == 201  # control: the default level is within the limit
    r = submit("4")
    assert r.status_code == 422, r.text
    assert "TESSERA_USER_MAX_TRANSLATED_BYTES" in r.json()["detail"]
    assert submit("2").status_code == 201  # the level's own verdict, not level 4's


def test_a_diced_job_is_held_to_the_translated_size_limit_at_its_diced_levels(api, tmp_path):
    """With dicing_rate the pre-flight dices as the workers will (the job's frame and
    camera): the same 400 quads seen from 2 units away in a 16-pixel frame have cage
    edges of about 1.5 pixels, so a rate of 4 px refines them once (3,200 triangles,
    within Bob's 1 MiB) and a rate of 0.05 px four times, the default maximum (204,800
    triangles, about 12 MB: over it). A verdict for one rate is not reused for another."""
    path = _row_of_cage_quads(tmp_path / "near_cage.usdc", camera_distance=2.0)

    def submit(rate: str) -> httpx.Response:
        data = {"width": "16", "height": "16", "spp": "1", "dicing_rate": rate}
        return api.post("/jobs", files={"file": (path.name, path.read_bytes())}, data=data,
                        headers={"Authorization": "Bearer bob-token"})

    r = submit("4")
    assert r.status_code == 201, r.text  # control: one level is within the limit
    r = submit("0.05")
    assert r.status_code == 422, r.text
    assert "TESSERA_USER_MAX_TRANSLATED_BYTES" in r.json()["detail"]
    assert submit("4").status_code == 201  # the rate's own verdict, not the finer one's
