"""The whole farm end to end: real redis-server, uvicorn API and worker processes.

The farm's merged image must equal a local render with the same settings bit for bit,
also when a worker dies mid-job and another takes over its tile."""
from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
import OpenImageIO as oiio
import pytest

from conftest import (CORNELL, STARTUP_TIMEOUT, Process, child_pids, clean_env, is_running, start_api,
                      start_worker, submit, wait_for_job)
from tessera_base import images, protocol
from tessera_queue import tasks as queue_tasks
from tessera_queue import redis_schema as rdb
from tessera_base.protocol import JobSpec, RenderSettings
from tessera_renderer import load_scene
from tessera_cli.embedded import free_port
from tessera_service.store import JobStore


@pytest.fixture(scope="module")
def farm(redis_server, tmp_path_factory):
    """The API and two workers ("w-a", "w-b") on one Redis."""
    logs = tmp_path_factory.mktemp("farm")
    api_proc, base = start_api(redis_server, logs)
    workers = {name: start_worker(redis_server, name, logs) for name in ("w-a", "w-b")}
    with httpx.Client(base_url=base, timeout=60) as client:
        client.processes = [api_proc, *workers.values()]
        client.workers = workers
        client.redis_url, client.log_dir = redis_server, logs
        yield client
    for proc in [*client.workers.values(), api_proc]:
        proc.stop()


def reference(settings: dict) -> np.ndarray:
    """The image rendered locally in one piece, in this process."""
    w, h = settings["width"], settings["height"]
    return load_scene(str(CORNELL)).render_tile(0, 0, w, h, width=w, height=h, spp=settings["spp"],
                                                seed=settings["seed"],
                                                max_depth=settings["max_depth"], threads=0)


def assert_farm_renders_the_cornell_box(farm, scene: Path, form: dict, out: Path) -> None:
    """`scene` submitted with `form` finishes, and its image is the local Cornell box's."""
    r = submit(farm, scene, **form)
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    assert_bit_identical(download_exr(farm, status["id"], out), reference(form))


def assert_bit_identical(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape and actual.dtype == expected.dtype == np.float32
    differ = actual.view(np.uint32) != expected.view(np.uint32)
    assert not differ.any(), (f"{int(differ.sum())} of {differ.size} channel values differ; "
                              f"first at {np.argwhere(differ)[0].tolist()}")


def download_exr(client: httpx.Client, job_id: str, path: Path) -> np.ndarray:
    r = client.get(f"/jobs/{job_id}/image.exr")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/x-exr"
    path.write_bytes(r.content)
    return images.read_exr(path)


def test_farm_image_equals_local_render(farm, redis_client, tmp_path):
    form = dict(width=72, height=56, spp=8, seed=3, max_depth=16, tile_size=16)  # 5x4 uneven grid
    r = submit(farm, CORNELL, **form)
    assert r.status_code == 201, r.text
    job = r.json()
    assert job["tiles_total"] == 20 and (job["width"], job["height"]) == (72, 56)

    status = wait_for_job(farm, job["id"], processes=farm.processes, expect="done")
    assert status["tiles_done"] == status["tiles_total"] == 20
    assert status["started_at"] and status["finished_at"] and status["render_seconds"] > 0
    assert status["error"] is None

    expected = reference(form)
    assert_bit_identical(download_exr(farm, job["id"], tmp_path / "farm.exr"), expected)

    r = farm.get(f"/jobs/{job['id']}/preview.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    (tmp_path / "farm.png").write_bytes(r.content)
    png = oiio.ImageBuf(str(tmp_path / "farm.png"))
    pixels = np.asarray(png.get_pixels(oiio.UINT8)).reshape(56, 72, 3)
    assert np.array_equal(pixels, images.tonemap_srgb8(expected))

    # Translated once: the first worker to load the scene stored the renderer's blob,
    # which the other workers load without parsing USD.
    from tessera_renderer import scene_blob
    version = f"v{scene_blob.BLOB_VERSION}.{scene_blob.TRANSLATOR_VERSION}"
    spec = protocol.JobSpec.model_validate_json(redis_client.hget(rdb.job_key(job["id"]), "spec"))
    digest = redis_client.hget(rdb.scene_key(spec.scene_hash), rdb.translated_field(version))
    assert digest and JobStore(redis_client).data.read_bytes(digest.decode()).startswith(scene_blob.MAGIC)
    # Held by the scene's hash: it goes with the scene, once no job holds it.
    assert redis_client.sismember(rdb.data_holders_key(digest.decode()), rdb.scene_key(spec.scene_hash))
    assert redis_client.pttl(rdb.scene_key(spec.scene_hash)) > 0

    # The merged files are cached: the same bytes again, without re-merging.
    assert redis_client.exists(rdb.job_image_key(job["id"], "exr"))
    assert farm.get(f"/jobs/{job['id']}/image.exr").content == (tmp_path / "farm.exr").read_bytes()


def test_bad_scenes_fail_cleanly_and_the_farm_goes_on(farm, redis_client, tmp_path):
    # Rejected at upload by the pre-flight.
    broken = tmp_path / "broken.usda"
    broken.write_text("#usda 1.0\ndef Mesh \"m\" { this is not usda }\n")
    r = submit(farm, broken)
    assert r.status_code == 422 and r.json()["detail"].startswith("the scene cannot be rendered:")

    # A scene that gets past the API but not the worker (queued straight into Redis):
    # the job fails with the loader's message, the workers keep running.
    store = JobStore(redis_client)
    garbage = f"#usda 1.0\n(((( garbage {uuid.uuid4().hex}".encode()
    scene_hash = hashlib.sha256(garbage).hexdigest()
    store.put_scene(scene_hash, "bad.usda", garbage)
    spec = JobSpec(job_id=uuid.uuid4().hex, scene_hash=scene_hash, scene_name="bad.usda",
                   settings=RenderSettings(width=32, height=32, spp=1, tile_size=16))
    store.create_job(spec, [])
    status = wait_for_job(farm, spec.job_id, processes=farm.processes)
    assert status["state"] == "failed", status
    assert "cannot load scene 'bad.usda'" in status["error"]
    r = farm.get(f"/jobs/{spec.job_id}/image.exr")
    assert r.status_code == 409 and "failed" in r.json()["detail"]

    # Everything still works afterwards.
    assert all(p.alive() for p in farm.processes), "\n".join(p.log() for p in farm.processes)
    assert_farm_renders_the_cornell_box(farm, CORNELL, dict(width=24, height=24, spp=2, seed=0, max_depth=8,
                                                            tile_size=8), tmp_path / "after.exr")


def test_sigterm_lets_the_worker_finish_its_tile(farm, redis_server, redis_client, tmp_path):
    """SIGTERM mid-tile: the worker renders and stores that tile, then exits cleanly."""
    worker = start_worker(redis_server, "w-c", tmp_path)
    try:
        r = submit(farm, CORNELL, width=64, height=64, spp=384, seed=5, max_depth=16, tile_size=16)
        assert r.status_code == 201, r.text
        job_id = r.json()["id"]
        queue = rdb.job_queue_key(job_id)
        deadline = time.monotonic() + 60
        while not (held := redis_client.xpending_range(
                queue, rdb.WORKER_GROUP, min="-", max="+", count=10, consumername="w-c")):
            assert time.monotonic() < deadline, "w-c never held a tile\n" + worker.log()
            time.sleep(0.01)
        entry_id = held[0]["message_id"]
        (_, fields), = redis_client.xrange(queue, entry_id, entry_id)
        task = queue_tasks.TileTask.from_fields(fields)
        assert task.job_id == job_id
        worker.popen.send_signal(signal.SIGTERM)
        assert worker.popen.wait(timeout=30) == 0, worker.log()
        assert f"job {job_id} tile {task.tile.index} pass 0 rendered" in worker.log(200), worker.log()
        assert redis_client.hexists(rdb.job_tiles_key(job_id), task.field)
        assert not redis_client.exists(rdb.worker_key("w-c"))
        assert not redis_client.sismember(rdb.WORKERS, "w-c")
        if redis_client.exists(queue):
            assert all(c["name"] != b"w-c" for c in
                       redis_client.xinfo_consumers(queue, rdb.WORKER_GROUP))
        status = wait_for_job(farm, job_id, processes=farm.processes, expect="done")
    finally:
        worker.stop()


def test_killed_worker_tile_is_taken_over(farm, redis_client, tmp_path):
    """SIGKILL a worker mid-tile: its heartbeat expires, the other worker claims the tile,
    and the image is still exactly the local render. The victim hangs on its tile (fault
    injection), so the job cannot end before the kill however fast the other worker is."""
    farm.workers["w-a"].stop()
    victim = farm.workers["w-a"] = start_worker(farm.redis_url, "w-a", farm.log_dir,
                                                faults="hang:victim*.usda")
    farm.processes[1] = victim
    scene = tmp_path / "victim.usda"
    shutil.copy(CORNELL, scene)
    form = dict(width=80, height=80, spp=384, seed=11, max_depth=16, tile_size=16)  # 25 tiles
    r = submit(farm, scene, **form)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    queue = rdb.job_queue_key(job_id)

    deadline = time.monotonic() + 60
    while not redis_client.xpending_range(queue, rdb.WORKER_GROUP, min="-", max="+",
                                          count=10, consumername="w-a"):
        assert time.monotonic() < deadline, "w-a never held a tile\n" + victim.log()
        time.sleep(0.01)
    os.kill(victim.pid, signal.SIGKILL)
    status = farm.get(f"/jobs/{job_id}").json()
    victim.popen.wait(timeout=10)
    assert status["state"] == "running"

    status = wait_for_job(farm, job_id, processes=farm.processes, expect="done")
    assert status["tiles_done"] == 25
    assert_bit_identical(download_exr(farm, job_id, tmp_path / "farm.exr"), reference(form))

    # The done job's queue is gone, the dead worker's heartbeat has expired and the
    # reapers forget it.
    assert not redis_client.exists(queue)
    assert not redis_client.exists(rdb.worker_key("w-a"))
    assert int(redis_client.hget(rdb.STATS, "reclaimed") or 0) >= 1
    deadline = time.monotonic() + 10
    while redis_client.sismember(rdb.WORKERS, "w-a"):
        assert time.monotonic() < deadline, "the dead worker's name was left behind"
        time.sleep(0.1)
    # Restart it for the tests that follow.
    farm.workers["w-a"] = start_worker(farm.redis_url, "w-a", farm.log_dir)
    farm.processes[1] = farm.workers["w-a"]


def test_a_layer_naming_its_stored_file_renders_as_it_passed_pre_flight(farm, tmp_path):
    """The pre-flight and every worker open an upload under one name, alone in its folder
    (protocol.scene_file_name): a layer that references @./scene.usda@ (itself, as the
    pre-flight saw it) renders on the workers too. (Workers used to name it by hash among
    other scenes: pre-flight said 201, the job failed.)"""
    scene = tmp_path / "self_reference.usda"
    scene.write_text(CORNELL.read_text() + '\ndef "Probe" (prepend references = @./scene.usda@</Cornell/Looks>) {}\n')
    # Materials only, referenced again: the image is the plain Cornell box's.
    assert_farm_renders_the_cornell_box(farm, scene, dict(width=16, height=16, spp=2, seed=3, max_depth=8,
                                                          tile_size=8), tmp_path / "farm.exr")


def test_embedded_serve_runs_a_whole_farm_and_stops_it(tmp_path):
    """`tessera serve` without a Redis URL: private redis-server + local worker + API; on
    SIGTERM everything it started is stopped."""
    port = free_port()
    serve = Process("serve", [sys.executable, "-m", "tessera", "serve", "--port", str(port),
                              "--workers", "1"], tmp_path, clean_env())
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while True:
            assert serve.alive(), serve.log()
            try:
                if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, serve.log()
            time.sleep(0.05)
        children = child_pids(serve.pid)
        assert len(children) == 2, children  # redis-server and one worker

        with httpx.Client(base_url=base, timeout=60) as client:
            r = submit(client, CORNELL, width=16, height=16, spp=1, tile_size=8)
            assert r.status_code == 201, r.text
            status = wait_for_job(client, r.json()["id"], processes=[serve], expect="done")

        serve.popen.send_signal(signal.SIGTERM)
        assert serve.popen.wait(timeout=30) == 0, serve.log()
        for pid in children:
            assert not is_running(pid), f"process {pid} outlived `tessera serve`"
    finally:
        serve.stop()


def _worker_children(pid: int) -> list[int]:
    return [c for c in child_pids(pid) if b"redis-server" not in Path("/proc", str(c), "cmdline").read_bytes()]


def test_embedded_serve_restarts_a_killed_worker(tmp_path):
    """`tessera serve --workers 1` with its worker SIGKILLed: the dead worker is reaped (no
    zombie), a new one is started, /healthz counts it, and a job submitted afterwards is
    rendered. (Before, the worker stayed a zombie and every job hung.)"""
    port = free_port()
    serve = Process("serve", [sys.executable, "-m", "tessera", "serve", "--port", str(port),
                              "--workers", "1"], tmp_path, clean_env())
    base = f"http://127.0.0.1:{port}"

    def wait_for(what, condition):
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while not condition():
            assert serve.alive(), serve.log()
            assert time.monotonic() < deadline, f"{what}: {serve.log()}"
            time.sleep(0.05)

    def health():
        try:
            return httpx.get(f"{base}/healthz", timeout=1).json()
        except httpx.TransportError:
            return {}

    try:
        wait_for("a live worker", lambda: health().get("workers") == 1)
        [first] = _worker_children(serve.pid)
        os.kill(first, signal.SIGKILL)
        wait_for("the killed worker reaped", lambda: not Path("/proc", str(first)).exists())
        wait_for("a new worker", lambda: len(_worker_children(serve.pid)) == 1)
        [second] = _worker_children(serve.pid)
        assert second != first and is_running(second)
        # The supervisor logs the restart after the new process is up: wait for the line.
        wait_for("the restart logged", lambda: "restarted a local worker" in serve.log())
        assert "restarting it in" in serve.log()
        with httpx.Client(base_url=base, timeout=60) as client:
            r = submit(client, CORNELL, width=16, height=16, spp=1, tile_size=8)
            assert r.status_code == 201, r.text
            status = wait_for_job(client, r.json()["id"], processes=[serve], expect="done")
    finally:
        serve.stop()


def test_worker_does_not_import_the_service():
    code = ("import sys, tessera_worker.worker; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('fastapi', 'starlette', 'uvicorn', 'tessera_service')); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)




@pytest.mark.parametrize("integrator, crop", [("bdpt", None), ("light", None), ("bdpt", (12, 4, 30, 20))],
                         ids=["bdpt", "light", "bdpt-crop"])
def test_splatting_integrators_on_the_farm_equal_a_local_render(farm, tmp_path, integrator, crop):
    """Light paths splat onto other tiles' pixels: the farm sums every tile's splat layer
    (exact integers) and normalises by all light paths, so the merged image equals the local
    render bit for bit, however the two workers shared the tiles; with a crop too, whose
    tiles skip their camera work outside it (docs/aovs.md, "Crop")."""
    from tessera.local import render_image

    form = dict(width=40, height=24, spp=4, seed=5, max_depth=8, tile_size=16, integrator=integrator)
    r = submit(farm, CORNELL, **form, **({"crop": ",".join(map(str, crop))} if crop else {}))
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    actual = download_exr(farm, status["id"], tmp_path / "farm.exr")
    local = render_image(load_scene(str(CORNELL)), RenderSettings(**form, crop=crop), progress=False,
                         variance=False).rgba
    images.write_exr(tmp_path / "local.exr", local, crop=crop)
    assert_bit_identical(actual, images.read_exr(tmp_path / "local.exr"))
    assert actual[..., :3].mean() > 0.01


@pytest.mark.parametrize("form", [
    dict(width=40, height=24, spp=4, seed=5, max_depth=8, tile_size=16),
    dict(width=40, height=24, seed=5, max_depth=8, tile_size=16, target_error=0.2, min_spp=2, max_spp=8),
    dict(width=40, height=24, spp=2, seed=5, max_depth=8, tile_size=16, integrator="bdpt"),
], ids=["fixed", "noise-target", "bdpt"])
def test_farm_aovs_equal_a_local_render(farm, tmp_path, form):
    """Tile results carry the AOVs; the merge combines passes (convergence.combine_aovs) and
    pastes tiles as the local render does, so every EXR channel equals the local one."""
    from tessera.local import render_image

    r = submit(farm, CORNELL, aovs="all", **form)
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    download_exr(farm, status["id"], tmp_path / "farm.exr")
    settings = RenderSettings(aovs="all", **form)
    local = render_image(load_scene(str(CORNELL)), settings, progress=False)
    from tessera_base.exr_header import noise_attributes

    local_meta = images.render_metadata(settings.max_spp if settings.adaptive else settings.spp, settings.seed,
                                        CORNELL.name, settings.integrator, local.variance_kind)
    local_meta.update(noise_attributes(settings.target_error, local.rgba, local.aovs.get("variance", local.variance),
                                       local.aovs.get("spp", local.spp), local.variance_kind))
    images.write_exr(tmp_path / "local.exr", local.rgba, local_meta, aovs=local.aovs)
    farm_channels = images.read_exr_channels(tmp_path / "farm.exr")
    local_channels = images.read_exr_channels(tmp_path / "local.exr")
    assert set(farm_channels) == set(local_channels) and "N.Y" in farm_channels and "Z" in farm_channels
    for name, values in local_channels.items():  # the variance too: bdpt's from batch means
        assert_bit_identical(farm_channels[name], values)
    # The same header: integrator, spp, seed, version, what the variance layer means and
    # the noise reached (the farm's from its merged layers).
    farm_meta, local_meta = (
        {k: v for k, v in images.read_render(tmp_path / f).metadata.items() if k.startswith("tessera:")}
        for f in ("farm.exr", "local.exr"))
    assert farm_meta == local_meta and farm_meta["tessera:integrator"] == settings.integrator
    assert farm_meta[images.VARIANCE_ATTRIBUTE] == (
        "batch-means:2" if settings.integrator == "bdpt" else "per-sample")  # bdpt: 2 spp, 2 batches
    assert set(farm_meta) >= {"tessera:spp", "tessera:seed", "tessera:version"}
    if "target_error" in form:
        assert len(np.unique(farm_channels["spp"])) > 1  # tiles stopped at different passes


def test_farm_denoised_layer_equals_the_local_one(farm, tmp_path):
    """A job with denoise=true: the merge adds the denoised layer (and the albedo and normal
    AOVs it needs) as the local render does, every channel bit for bit, and
    /jobs/ID/denoised.png is that layer tonemapped. Control: a job without denoise has no
    denoised layer and its denoised.png is refused (409)."""
    from tessera.local import render_image

    form = dict(width=48, height=40, spp=4, seed=2, max_depth=8, tile_size=16)
    r = submit(farm, CORNELL, denoise="true", **form)
    assert r.status_code == 201, r.text
    status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
    assert status["settings"]["denoise"] is True
    assert status["settings"]["aovs"] == ["albedo", "normal"]
    download_exr(farm, status["id"], tmp_path / "farm.exr")
    farm_channels = images.read_exr_channels(tmp_path / "farm.exr")
    local = render_image(load_scene(str(CORNELL)), RenderSettings(denoise=True, **form), progress=False)
    assert local.denoise_warning is None and "denoised" in local.aovs
    for i, name in enumerate(images.AOV_EXR_CHANNELS["denoised"]):
        assert_bit_identical(farm_channels[name], np.ascontiguousarray(local.aovs["denoised"][..., i]))
    for i, name in enumerate("RGBA"):
        assert_bit_identical(farm_channels[name], np.ascontiguousarray(local.rgba[..., i]))
    r = farm.get(f"/jobs/{status['id']}/denoised.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    (tmp_path / "denoised.png").write_bytes(r.content)
    png = oiio.ImageBuf(str(tmp_path / "denoised.png")).get_pixels(oiio.UINT8)
    assert np.array_equal(png, images.tonemap_srgb8(local.aovs["denoised"]))

    r = submit(farm, CORNELL, **form)
    plain = wait_for_job(farm, r.json()["id"], processes=farm.processes)
    assert plain["state"] == "done", plain
    download_exr(farm, plain["id"], tmp_path / "plain.exr")
    assert not set(images.AOV_EXR_CHANNELS["denoised"]) & set(images.read_exr_channels(tmp_path / "plain.exr"))
    r = farm.get(f"/jobs/{plain['id']}/denoised.png")
    assert r.status_code == 409 and "denoise=true" in r.json()["detail"]


def test_submit_auto_sends_one_measured_choice_that_the_farm_records(farm, tmp_path):
    """`tessera submit --integrator auto` runs the pilot on the client and sends its choice
    and numbers: the job log names them, every worker renders that integrator (the image
    equals a local render with it, bit for bit) and the EXR carries tessera:auto."""
    import json

    from tessera.local import render_image
    from tessera.pilot import PilotRow, choose

    out = tmp_path / "auto.exr"
    proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(CORNELL), "--server", str(farm.base_url),
                           "--integrator", "auto", "--res", "40x24", "--spp", "4", "--seed", "5", "--max-depth", "8",
                           "--tile", "16", "--wait", "-q", "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "auto chose " in proc.stderr, proc.stderr
    spec = oiio.ImageInput.open(str(out)).spec()
    pilot = json.loads(spec.getattribute("tessera:auto"))
    assert pilot["choice"] == choose([PilotRow(**row) for row in pilot["rows"]])
    assert spec.getattribute("tessera:integrator") == pilot["choice"]
    job = next(j for j in farm.get("/jobs").json()["jobs"] if j["settings"].get("auto_pilot"))
    assert json.loads(job["settings"]["auto_pilot"]) == pilot and job["settings"]["integrator"] == pilot["choice"]
    log = farm.get(f"/jobs/{job['id']}/log").json()["lines"]
    assert any(f"integrator {pilot['choice']} chosen by the client's auto pilot" in line for line in log), log
    form = dict(width=40, height=24, spp=4, seed=5, max_depth=8, tile_size=16, integrator=pilot["choice"])
    local = render_image(load_scene(str(CORNELL)), RenderSettings(**form), progress=False, variance=False).rgba
    images.write_exr(tmp_path / "local.exr", local)
    assert_bit_identical(images.read_exr(out), images.read_exr(tmp_path / "local.exr"))


def test_the_same_bytes_as_usdz_and_zip_render_their_own_roots(farm, redis_client, tmp_path):
    """One archive, two readings: as .usdz its root is the first member (the Cornell box),
    as .zip the one its comment names (the box with its emitter off, and no default
    light: black). Each renders
    its own root, bit-identical to the local render of that layer: the workers keep the
    .usdz's translated scene apart from the .zip's (shared by content hash alone, the
    second job would have rendered the first one's scene)."""
    import zipfile

    form = dict(width=24, height=16, spp=2, seed=3, max_depth=4, tile_size=8)
    box = CORNELL.read_text()
    unlit = box.replace("inputs:emissiveColor = (17, 12, 4)", "inputs:emissiveColor = (0, 0, 0)")
    assert unlit != box, "the Cornell box's emitter changed: update this test"
    archive = tmp_path / "roots.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("box.usda", box)
        zf.writestr("dark.usda", unlit)
        zf.comment = b"tessera-entry: dark.usda"
    data = archive.read_bytes()
    images_by_suffix = {}
    for name in ("roots.usdz", "roots.zip"):
        r = farm.post("/jobs", files={"file": (name, data)},
                      data={k: str(v) for k, v in form.items()} | {"default_light": "false"})
        assert r.status_code == 201, r.text
        status = wait_for_job(farm, r.json()["id"], processes=farm.processes, expect="done")
        images_by_suffix[name] = download_exr(farm, status["id"], tmp_path / f"{name}.exr")
    assert_bit_identical(images_by_suffix["roots.usdz"], reference(form))
    assert images_by_suffix["roots.usdz"][..., :3].max() > 0
    assert images_by_suffix["roots.zip"][..., :3].max() == 0  # lit by nothing
