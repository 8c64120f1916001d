"""Issue 43 on the farm: a job whose merged image is black for its exposure gets one
warning (its status and its log, once however often the image is fetched) naming the
brightest light its pre-flight found, as a local render prints it
(tests/renderer/test_black_image_warning.py)."""
from __future__ import annotations

import subprocess
import sys

from conftest import api_client, clean_env, farm_image, start_worker, submit, wait_for_job
from tessera_base.film import BLACK_PIXEL, BLACK_SHARE
from usd_fixtures import DIM_SPHERE_LIGHT_USDA


FORM = {"spp": 2, "tile_size": 16, "integrator": "path", "width": 24, "height": 24}


def test_a_black_farm_image_names_its_brightest_light(redis_server, tmp_path):
    (tmp_path / "logs").mkdir()
    with api_client(redis_server, tmp_path / "logs") as farm:
        worker = start_worker(farm.redis_url, "black-0", farm.log_dir)
        try:
            for intensity, black in ((10, True), (1000000, False)):  # the second: negative control
                scene = tmp_path / f"dim{intensity}.usda"
                scene.write_text(DIM_SPHERE_LIGHT_USDA.replace("INTENSITY", str(intensity)))
                r = submit(farm, scene, **FORM)
                assert r.status_code == 201, r.text
                job = r.json()["id"]
                wait_for_job(farm, job, timeout=120, processes=[worker], expect="done")
                image = farm_image(farm, job, tmp_path)
                assert (float((image[..., :3].max(axis=-1) < BLACK_PIXEL).mean()) >= BLACK_SHARE) is black
                assert farm.get(f"/jobs/{job}/preview.png").status_code == 200  # a second merge
                warnings = [w for w in farm.get(f"/jobs/{job}").json()["warnings"] if "black for its exposure" in w]
                log = [ln for ln in farm.get(f"/jobs/{job}/log").json()["lines"] if "black for its exposure" in ln]
                if black:
                    assert len(warnings) == 1 and "/Light (SphereLight, intensity 10)" in warnings[0], warnings
                    assert len(log) == 1, log
                else:
                    assert warnings == [] and log == []
                # `tessera submit --wait` prints it once the image it downloads is merged.
                proc = subprocess.run([sys.executable, "-m", "tessera", "submit", str(scene), "--server",
                                       str(farm.base_url), "--wait", "-q", "-o", str(tmp_path / "cli.exr"),
                                       "--res", "24x24", "--spp", "2", "--tile", "16"],
                                      env=clean_env(), capture_output=True, text=True, timeout=300)
                assert proc.returncode == 0, proc.stderr
                printed = [ln for ln in proc.stderr.splitlines() if "black for its exposure" in ln]
                assert len(printed) == (1 if black else 0), proc.stderr
        finally:
            worker.stop()
