"""Frame ranges on the farm: POST /jobs with `frames` queues one job per frame under one
sequence id; each frame equals a local render at that time code bit for bit; the
sequence reports every frame's state (a cancelled frame is named), cancels as a whole,
and `tessera submit --frames --wait` writes numbered EXRs."""
from __future__ import annotations

import json
from datetime import datetime
import subprocess
import sys

import numpy as np

from conftest import api_client, start_worker, submit, wait_for_job
from tessera import local
from tessera_base import images
from tessera_base.protocol import RenderSettings
from tessera_renderer import load_scene
from test_farm_motion import SCENE

FORM = {"spp": 4, "tile_size": 24, "integrator": "path"}


def _local(scene, frame):
    settings = RenderSettings(width=48, height=48, **FORM)
    return local.render_image(load_scene(scene, frame=frame), settings, progress=False, variance=False).rgba


def _same(a, b):
    return np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_a_frame_range_renders_each_frame_as_a_local_render_does(redis_server, tmp_path):
    scene = tmp_path / "moving_ball.usda"
    scene.write_text(SCENE)
    expected = {f: _local(scene, f) for f in (1, 2, 3)}
    assert not _same(expected[1], expected[3])  # the ball moves between frames
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        # Refused before anything is queued.
        for form, words in (({"frames": "3-1"}, "must run upwards"), ({"frames": "1-2", "frame": 1}, "not both"),
                            ({"frames": "x"}, "is not a frame")):
            r = submit(farm, scene, spp=1, **form)
            assert r.status_code == 422 and words in r.text, r.text

        # A sequence queued with no worker: one frame cancelled, the rest rendered.
        r = submit(farm, scene, **FORM, frames="3,1-2")
        assert r.status_code == 201, r.text
        created = r.json()
        seq = created["id"]
        assert r.headers["Location"] == f"/jobs/{seq}"
        assert [f["frame"] for f in created["frames"]] == [3, 1, 2]
        assert created["tiles_total"] == 3 * 4
        jobs = {f["frame"]: f["job"] for f in created["frames"]}
        status = farm.get(f"/jobs/{seq}").json()
        assert status["kind"] == "sequence" and status["state"] == "queued", status
        assert farm.delete(f"/jobs/{jobs[2]}").json()["state"] == "cancelled"
        worker = start_worker(farm.redis_url, "frames-0", farm.log_dir)
        try:
            for f in (3, 1):
                frame_status = wait_for_job(farm, jobs[f], timeout=120, processes=[worker], expect="done")
                assert frame_status["settings"]["frame"] == f
            status = farm.get(f"/jobs/{seq}").json()
            assert [(f["frame"], f["state"]) for f in status["frames"]] == \
                [(3, "done"), (1, "done"), (2, "cancelled")], status
            assert status["state"] == "cancelled" and status["tiles_done"] == 8, status
            for f in (3, 1):
                r = farm.get(f"/jobs/{seq}/frames/{f}/image.exr")
                assert r.status_code == 200, r.text
                path = tmp_path / f"farm.{f}.exr"
                path.write_bytes(r.content)
                assert _same(images.read_exr(path), expected[f]), f"frame {f} differs from the local render"
            assert farm.get(f"/jobs/{seq}/frames/2/image.exr").status_code == 409  # cancelled: no image
            r = farm.get(f"/jobs/{seq}/frames/7/image.exr")
            assert r.status_code == 404 and "frame 7 is not one of the frames" in r.text, r.text
            assert farm.get(f"/jobs/{seq}/frames/1/preview.png").headers["content-type"] == "image/png"

            # The CLI: a frame range submitted, followed and downloaded as numbered EXRs.
            out = tmp_path / "cli" / "shot.####.exr"
            proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(scene), "--server",
                                   str(farm.base_url), "--frames", "1-3x2", "--wait", "-q", "-o", str(out),
                                   "--spp", "4", "--tile", "24", "--integrator", "path"],
                                  capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, proc.stderr + worker.log()
            for f in (1, 3):
                assert _same(images.read_exr(tmp_path / "cli" / f"shot.{f:04d}.exr"), expected[f]), f
            assert not (tmp_path / "cli" / "shot.0002.exr").exists()
        finally:
            worker.stop()

        # DELETE on the sequence cancels every frame.
        r = submit(farm, scene, **FORM, frames="1-2")
        seq = r.json()["id"]
        status = farm.delete(f"/jobs/{seq}").json()
        assert status["state"] == "cancelled" and {f["state"] for f in status["frames"]} == {"cancelled"}, status
        assert farm.get("/jobs/" + "0" * 32).status_code == 404


def test_a_frame_range_is_paused_resumed_reprioritised_logged_and_followed_as_one(redis_server, tmp_path):
    """The sequence id stands for all its frames: pause, resume and priority reach every
    frame's job, the log holds every frame's lines naming the frame, and the events stream
    merges every frame's events (each naming its frame) and ends when the last is final."""
    scene = tmp_path / "moving_ball.usda"
    scene.write_text(SCENE)
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        seq = submit(farm, scene, **FORM, frames="1-3").json()["id"]
        status = farm.post(f"/jobs/{seq}/pause").json()
        assert status["kind"] == "sequence" and {f["state"] for f in status["frames"]} == {"paused"}, status
        assert status["state"] == "paused"
        status = farm.post(f"/jobs/{seq}/priority", json={"priority": 7}).json()
        assert status["kind"] == "sequence"
        assert {farm.get(f"/jobs/{f['job']}").json()["priority"] for f in status["frames"]} == {7}
        status = farm.post(f"/jobs/{seq}/resume").json()
        assert {f["state"] for f in status["frames"]} == {"queued"}, status
        worker = start_worker(farm.redis_url, "frames-1", farm.log_dir)
        try:
            events = []
            with farm.stream("GET", f"/jobs/{seq}/events") as response:
                assert response.status_code == 200
                for line in response.iter_lines():
                    if line.startswith("data: "):
                        events.append(json.loads(line[6:]))
        finally:
            worker.stop()
        finals = sorted(e["frame"] for e in events if e["type"] == "state" and e["state"] == "done")
        assert finals == [1, 2, 3], events
        tiles = [e for e in events if e["type"] == "tile"]
        assert sorted((e["frame"], e["tile"]) for e in tiles) == [(f, t) for f in (1, 2, 3) for t in range(4)]
        assert farm.get(f"/jobs/{seq}").json()["state"] == "done"
        lines = farm.get(f"/jobs/{seq}/log").json()["lines"]
        for f in (1, 2, 3):
            assert any(f" frame {f}: " in line and "paused" in line for line in lines), lines
        stamps = [datetime.fromisoformat(line.split(" ", 1)[0]) for line in lines]
        assert stamps == sorted(stamps)
