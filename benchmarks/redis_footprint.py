"""Redis bytes one job keeps: the numbers of issue 14 item 3 (splat layers filling Redis).

    .venv/bin/python benchmarks/redis_footprint.py --label after

A private Redis, the API (uvicorn) and two 1-thread workers, as separate processes; each
job of CASES (the Cornell box) is submitted over HTTP and, once done and before its image
is downloaded (the cached EXR/PNG are not counted), every key of the job is measured with
MEMORY USAGE (SAMPLES 0: every field). The same script measured the code before the change
(run with that code first on the path, `--label before`). Results are merged by label into
docs/benchmarks/redis-footprint.{json,md}, with the bound the service checks
(redis_schema.job_storage_bound) when this code has it.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack

import httpx
import redis
from common import CORNELL, OUT

CASES = [
    dict(name="bdpt 256² 16 spp, tiles 64", integrator="bdpt", width=256, height=256, spp=16, tile_size=64),
    dict(name="bdpt 256² 16 spp, tiles 32", integrator="bdpt", width=256, height=256, spp=16, tile_size=32),
    dict(name="bdpt 512² 4 spp, tiles 64", integrator="bdpt", width=512, height=512, spp=4, tile_size=64),
    dict(name="bdpt 256² 16 spp, tiles 64, variance AOV", integrator="bdpt", width=256, height=256,
         spp=16, tile_size=64, aovs="variance"),
    dict(name="path 256² 16 spp, tiles 64", integrator="path", width=256, height=256, spp=16, tile_size=64),
]


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure(workdir: str) -> list[dict]:
    from tessera_cli.embedded import redis_server, stop_processes

    env = {k: v for k, v in os.environ.items() if not k.startswith("TESSERA_") and k != "REDIS_URL"}
    out = []
    with ExitStack() as stack:
        url = stack.enter_context(redis_server(workdir)).url
        port = _free_port()
        procs = [subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory",
                                   "tessera_service.app:create_app", "--port", str(port),
                                   "--log-level", "warning"],
                                  env=dict(env, TESSERA_REDIS_URL=url), stdin=subprocess.DEVNULL)]
        for i in range(2):
            procs.append(subprocess.Popen([sys.executable, "-m", "tessera_worker", "--name", f"w{i}",
                                           "--threads", "1", "--log-level", "WARNING"],
                                          env=dict(env, REDIS_URL=url), stdin=subprocess.DEVNULL))
        stack.callback(stop_processes, procs, 10.0)
        client = redis.Redis.from_url(url)
        http = stack.enter_context(httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120))
        deadline = time.monotonic() + 60
        while True:
            try:
                if http.get("/healthz").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the API did not start")
            time.sleep(0.1)
        for case in CASES:
            form = {k: str(v) for k, v in case.items() if k != "name"}
            with open(CORNELL, "rb") as f:
                r = http.post("/jobs", files={"file": (CORNELL.name, f)}, data=form)
            r.raise_for_status()
            job_id = r.json()["id"]
            while (state := http.get(f"/jobs/{job_id}").json()["state"]) not in ("done", "failed", "cancelled"):
                time.sleep(0.2)
            if state != "done":
                raise RuntimeError(f"{case['name']}: job {state}")
            sizes = {}
            for key in client.scan_iter(match=f"tessera:job:{job_id}*", count=1000):
                sizes[key.decode().split(job_id, 1)[1] or "(job hash)"] = client.memory_usage(key, samples=0)
            row = dict(case=case["name"], settings=form, bytes=sum(sizes.values()), keys=sizes)
            try:
                from tessera_queue import redis_schema
                from tessera_base.protocol import RenderSettings
                row["bound"] = redis_schema.job_storage_bound(RenderSettings(**{
                    k: v for k, v in case.items() if k != "name"}))
            except ImportError:
                pass
            print(f"{case['name']}: {row['bytes'] / 1e6:.2f} MB", {k: v for k, v in sizes.items() if v > 10000},
                  flush=True)
            out.append(row)
    return out


def write(label: str, rows: list[dict]) -> None:
    path = OUT / "redis-footprint.json"
    data = json.loads(path.read_text()) if path.exists() else {}
    data[label] = {"rows": rows, "machine": platform.platform(), "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    path.write_text(json.dumps(data, indent=1) + "\n")
    labels = [k for k in ("before", "after") if k in data] + [k for k in data if k not in ("before", "after")]
    lines = ["# Redis bytes per job", "",
             "Written by `benchmarks/redis_footprint.py` (method in its docstring): every key of one",
             "finished job, measured with `MEMORY USAGE` before its image is downloaded. *before*: the",
             "code where every light/bdpt tile stored a full-frame splat layer; *after*: tiles store",
             "their own pixels and the splats are summed into one layer per pass",
             "(`tessera/tessera_base/film.py` SplatSums, `docs/farm.md` \"Memory per job\"). *bound*: what the",
             "service estimates before queuing the job and compares with `TESSERA_JOB_REDIS_BUDGET`.",
             "", "| job | " + " | ".join(f"{k} (MB)" for k in labels) + " | bound (MB) |",
             "|---|" + "---|" * (len(labels) + 1)]
    for i, case in enumerate(CASES):
        cells, bound = [], ""
        for k in labels:
            rows_k = data[k]["rows"]
            cells.append(f"{rows_k[i]['bytes'] / 1e6:.2f}" if i < len(rows_k) else "")
            if i < len(rows_k) and "bound" in rows_k[i]:
                bound = f"{rows_k[i]['bound'] / 1e6:.2f}"
        lines.append(f"| {case['name']} | " + " | ".join(cells) + f" | {bound} |")
    lines += ["", "Measured on: " + ", ".join(f"{k}: {data[k]['measured_at']} ({data[k]['machine']})" for k in labels), ""]
    (OUT / "redis-footprint.md").write_text("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--label", required=True, help="before or after (or any name)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="tessera-footprint-") as tmp:
        rows = measure(tmp)
    write(args.label, rows)


if __name__ == "__main__":
    main()
