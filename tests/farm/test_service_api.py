"""The HTTP API against a real redis-server and a real uvicorn process (no workers here:
jobs stay queued unless cancelled)."""
from __future__ import annotations

import re
import subprocess
import sys

import httpx
import pytest

from conftest import CORNELL, start_api, submit
from tessera_base import protocol
from tessera_queue import redis_schema as rdb

UPLOAD_LIMIT = 64 * 1024


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("api"),
                           max_upload_bytes=UPLOAD_LIMIT)
    with httpx.Client(base_url=base, timeout=60) as client:
        yield client
    proc.stop()


def test_healthz_says_degraded_without_workers(api):
    """The API and Redis answer (200), but no worker renders: the body says so."""
    r = api.get("/healthz")
    assert r.status_code == 200
    assert r.json() == {"status": "degraded", "redis": True, "workers": 0,
                        "problems": ["no worker is alive (no current heartbeat)"]}


def test_healthz_says_degraded_when_the_queue_has_not_moved(api, redis_client):
    """A queued job whose newest event is old (its stream rewritten to one event at 1970)
    is a stalled queue beyond the default 600 s; cancelled, it no longer counts."""
    job = submit(api, CORNELL, spp=1, tile_size=256).json()["id"]
    try:
        events = rdb.job_events_key(job)
        redis_client.delete(events)
        redis_client.xadd(events, {"type": "state"}, id="1000-0")
        problems = api.get("/healthz").json()["problems"]
        assert any("have not progressed for" in p for p in problems), problems
    finally:
        api.delete(f"/jobs/{job}")
    assert not any("progressed" in p for p in api.get("/healthz").json()["problems"])


def test_unknown_job_is_404(api):
    for path in ("/jobs/nope", "/jobs/nope/image.exr", "/jobs/nope/preview.png"):
        r = api.get(path)
        assert r.status_code == 404, path
        assert "no job with id 'nope'" in r.json()["detail"]
    assert api.delete("/jobs/nope").status_code == 404


def test_bad_suffix_is_400(api, tmp_path):
    scene = tmp_path / "model.obj"
    scene.write_text("v 0 0 0\n")
    r = submit(api, scene)
    assert r.status_code == 400
    assert "'.obj'" in r.json()["detail"] and ".usda" in r.json()["detail"]
    r = api.post("/jobs", files={"file": ("noext", b"#usda 1.0\n")})
    assert r.status_code == 400 and "no suffix" in r.json()["detail"]


def test_missing_file_is_422(api):
    r = api.post("/jobs", data={"spp": "4"})
    assert r.status_code == 422
    assert any(e["loc"][-1] == "file" for e in r.json()["detail"])


def test_oversize_upload_is_413(api):
    limit_text = f"{UPLOAD_LIMIT} bytes"
    # Just over the limit: caught while the file is saved.
    r = api.post("/jobs", files={"file": ("big.usda", b"#usda 1.0\n" + b" " * UPLOAD_LIMIT)})
    assert r.status_code == 413
    assert "larger than the limit" in r.json()["detail"] and limit_text in r.json()["detail"]
    # Far over: refused from Content-Length before the body is read.
    r = api.post("/jobs", files={"file": ("huge.usda", b" " * (3 << 20))})
    assert r.status_code == 413 and limit_text in r.json()["detail"]


def test_oversize_chunked_upload_is_413(api):
    """Without a Content-Length, the streamed body is cut off once it exceeds the limit."""
    boundary = "tesseraboundary"
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
            f"filename=\"huge.usda\"\r\nContent-Type: application/octet-stream\r\n\r\n").encode()

    def body():
        yield head
        for _ in range(48):  # 3 MiB
            yield b" " * (64 * 1024)
        yield f"\r\n--{boundary}--\r\n".encode()

    try:
        r = api.post("/jobs", content=body(),
                     headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    except httpx.TransportError:
        # The server may answer and close before the client has sent everything; then
        # at least it must still be serving.
        assert api.get("/healthz").status_code == 200
        return
    assert r.status_code == 413
    assert "larger than the limit" in r.json()["detail"]


def test_malformed_usd_is_422_with_message(api, tmp_path):
    scene = tmp_path / "broken.usda"
    scene.write_text("this is not a USD layer {{{\n")
    r = submit(api, scene)
    assert r.status_code == 422
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail.startswith("the scene cannot be rendered:")
    assert len(detail) > len("the scene cannot be rendered: ") + 5


def test_usd_errors_speak_of_the_bundle_not_the_server(api, tmp_path):
    """A parse error names the line in the uploaded layer, without the server's temporary
    directory, USD's source files, C++ namespaces or pointer addresses."""
    scene = tmp_path / "cut.usda"
    scene.write_text('#usda 1.0\ndef Mesh "M" {\n  point3f[] points = [(0,0,\n')
    r = submit(api, scene)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert ".usda:4:1: parse error" in detail and "</M.points>" in detail, detail
    for leak in ("/tmp", "tessera-upload", "pxrInternal", "textParserHelpers", "0x"):
        assert leak not in detail, (leak, detail)


@pytest.mark.parametrize("field,value", [("spp", "0"), ("tile_size", "4"), ("width", "-3"),
                                         ("seed", "-1"), ("max_depth", "abc")])
def test_bad_settings_are_422_naming_the_field(api, field, value):
    r = submit(api, CORNELL, **{field: value})
    assert r.status_code == 422, r.text
    assert any(e["loc"][-1] == field for e in r.json()["detail"]), r.text


@pytest.mark.parametrize("field,value", [("target_error", "nan"), ("target_error", "inf"),
                                         ("time_limit", "nan"), ("time_limit", "-inf")])
def test_non_finite_settings_are_422_not_500(api, field, value):
    """JSON has no NaN: the validation error used to fail to encode its own input."""
    form = {field: value, **({"target_error": "0.05"} if field == "time_limit" else {})}
    r = submit(api, CORNELL, **form)
    assert r.status_code == 422, r.text
    errors = [e for e in r.json()["detail"] if e["loc"][-1] == field]
    assert errors and "finite" in errors[0]["msg"], r.text


def test_ids_that_are_not_job_ids_are_404_before_any_key_is_built(api):
    """A real id with a key suffix ("<id>:tiles") must not reach the Redis keys built
    from it (it gave 500s and a broken event stream)."""
    job = submit(api, CORNELL, spp=1, tile_size=256).json()["id"]
    try:
        assert api.get(f"/jobs/{job}").status_code == 200  # the control: the id itself works
        for bad in (f"{job}:tiles", f"{job}:events", job.upper(), job[:-1]):
            for method, path in (("GET", ""), ("GET", "/log"), ("GET", "/events"), ("GET", "/image.exr"),
                                 ("GET", "/preview.png"), ("DELETE", ""), ("POST", "/pause"), ("POST", "/resume")):
                r = api.request(method, f"/jobs/{bad}{path}")
                assert r.status_code == 404, (method, bad, path, r.status_code, r.text)
                assert "no job with id" in r.json()["detail"]
    finally:
        api.delete(f"/jobs/{job}")


def test_submit_uses_scene_resolution_and_creates_tiles(api, redis_client):
    r = submit(api, CORNELL, spp=4, tile_size=100)
    assert r.status_code == 201, r.text
    job = r.json()
    assert r.headers["location"] == f"/jobs/{job['id']}"
    assert (job["width"], job["height"]) == (512, 512)  # the example's RenderSettings
    assert job["state"] == "queued" and job["tiles_total"] == 36
    assert redis_client.zscore(rdb.JOB_INDEX, job["id"]) is not None
    status = api.get(f"/jobs/{job['id']}").json()
    assert status["settings"] == {"width": 512, "height": 512, "spp": 4, "seed": 0,
                                  "max_depth": 64, "tile_size": 100, "target_error": None,
                                  "min_spp": 16, "max_spp": 1024, "time_limit": None,
                                  "integrator": "path", "auto_pilot": None, "integrator_params": {}, "aovs": [],
                                  "default_light": True, "denoise": False, "crop": None,
                                  "subdivision_level": None, "camera": None,
                                  "frame": None, "shutter": None, "variants": None}
    assert status["priority"] == protocol.DEFAULT_PRIORITY
    # One queue entry per tile, and the job is ready to be served.
    assert redis_client.xlen(rdb.job_queue_key(job["id"])) == 36
    assert redis_client.zscore(rdb.READY, job["id"]) is not None
    assert status["tiles_done"] == 0 and status["scene_name"] == "cornell.usda"
    api.delete(f"/jobs/{job['id']}")


def test_too_many_tiles_is_422(api):
    r = submit(api, CORNELL, width=16384, height=16384, tile_size=8)
    assert r.status_code == 422 and "tile_size" in r.json()["detail"]


def test_cancel(api):
    r = submit(api, CORNELL, width=40, height=30, spp=2, tile_size=16)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    assert api.get(f"/jobs/{job_id}").json()["state"] == "queued"

    r = api.get(f"/jobs/{job_id}/image.exr")
    assert r.status_code == 409 and "queued" in r.json()["detail"]

    r = api.delete(f"/jobs/{job_id}")
    assert r.status_code == 200
    status = r.json()
    assert status["state"] == "cancelled" and status["finished_at"] is not None
    assert api.get(f"/jobs/{job_id}").json()["state"] == "cancelled"
    # cancelling again leaves it as it is
    assert api.delete(f"/jobs/{job_id}").json()["finished_at"] == status["finished_at"]
    for path in ("image.exr", "preview.png"):
        r = api.get(f"/jobs/{job_id}/{path}")
        assert r.status_code == 409 and "cancelled" in r.json()["detail"]


def test_service_does_not_import_renderer_or_usd():
    code = ("import sys, tessera_service.app, tessera_service.embedded; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('pxr', 'tessera_renderer')); "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_default_light_job_setting_and_its_warning(api, tmp_path):
    """A light-less scene: by default the job is lit by the default lighting and says so;
    with default_light=false its one light warning says it renders black."""
    scene = tmp_path / "prop.usda"
    scene.write_text('#usda 1.0\ndef Mesh "Tri" {\n  point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]\n'
                     '  int[] faceVertexCounts = [3]\n  int[] faceVertexIndices = [0, 1, 2]\n}\n')
    for form, expected in (({}, "lit by the default lighting"),
                           ({"default_light": "false"}, "default lighting is off: it renders black")):
        r = submit(api, scene, spp=1, tile_size=256, **form)
        assert r.status_code == 201, r.text
        job = r.json()
        try:
            lines = [w for w in job["warnings"] if "no lights" in w]
            assert len(lines) == 1 and expected in lines[0], job["warnings"]
            assert api.get(f"/jobs/{job['id']}").json()["settings"]["default_light"] is (not form)
        finally:
            api.delete(f"/jobs/{job['id']}")


def test_a_job_names_the_curves_its_integrator_cannot_shade(api, tmp_path):
    """The pre-flight counts the scene's curve segments; a radiosity job on it says in one
    warning that they render black, a path job does not."""
    scene = tmp_path / "strand.usda"
    scene.write_text('#usda 1.0\ndef BasisCurves "Hair" {\n  uniform token type = "linear"\n'
                     '  point3f[] points = [(-1,0,0), (1,0,0)]\n  int[] curveVertexCounts = [2]\n'
                     '  float[] widths = [0.2] (interpolation = "constant")\n}\n')
    for integrator, expected in (("radiosity", 1), ("path", 0)):
        r = submit(api, scene, spp=1, tile_size=256, integrator=integrator)
        assert r.status_code == 201, r.text
        job = r.json()
        try:
            lines = [w for w in job["warnings"] if "does not shade curves (1 curve segments)" in w]
            assert len(lines) == expected, job["warnings"]
        finally:
            api.delete(f"/jobs/{job['id']}")


def test_the_log_shows_iso_times(api, redis_client):
    """GET /jobs/{id}/log writes each line's time in ISO 8601 UTC (it was the raw epoch
    float, '1796651350.3275216 job queued ...'): the stored line's instant truncated to the
    millisecond, and the same message."""
    from datetime import datetime

    job = submit(api, CORNELL, spp=1, tile_size=256).json()["id"]
    try:
        stored = [line.decode() for line in redis_client.lrange(rdb.job_log_key(job), 0, -1)]
        lines = api.get(f"/jobs/{job}/log").json()["lines"]
        assert stored and len(lines) == len(stored)
        for raw, shown in zip(stored, lines):
            epoch, _, message = raw.partition(" ")
            stamp, _, rest = shown.partition(" ")
            assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00", stamp), shown
            # Truncated to the millisecond (a line's time never moves later).
            assert 0 <= float(epoch) - datetime.fromisoformat(stamp).timestamp() < 0.001 + 1e-6
            assert rest == message
    finally:
        api.delete(f"/jobs/{job}")
