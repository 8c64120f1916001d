"""Farm benchmarks: the numbers of the farm's closing note, measured in one run.

    .venv/bin/python benchmarks/farm.py [--repeats 3] [--quick]

1. Farm efficiency = local render time / farm time for the same image: Cornell box
   512x512, 64 spp, default tile size (64). Local: 2 threads in this process. Farm: a
   private Redis, the API (uvicorn) and two 1-thread workers; HTTP submit -> done -> EXR
   downloaded. Local and farm runs alternate so that drifting machine load hits both.
2. Per-tile dispatch overhead: one 1-thread worker, 256 tiles of 8x8 at 1 spp: (farm wall
   time - the worker's summed render time) / tiles.
3. Queue throughput with trivially small tiles: two workers, 1024 tiles of 8x8 at 1 spp.
4. Time to recover a dead worker's tiles: a worker holding a long tile is SIGKILLed; time
   until another worker has claimed the tile, with a 5 s heartbeat TTL (the default).
5. Noise target: a Cornell box seen from far away (much black background, uneven
   difficulty), 128x128, tiles of 16, rendered locally (2 threads) to a 5 % noise target
   (16..1024 spp) vs. at the fixed spp that gives the hardest tile the same error (the
   largest sample count the noise-target render needed anywhere). Reports the time ratio
   and the worst tile error of both.

Every figure is the median of its repeats with the half-range (min..max) as its error;
ratios are formed per repeat pair. Results go to docs/benchmarks/farm.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import httpx
import redis
from common import CORNELL, OUT, fmt, summary


class Farm:
    """Redis + API + workers as separate processes, like a deployment on one host."""

    def __init__(self, stack: ExitStack, workdir: str, workers: int, heartbeat_ttl: float = 5.0):
        from tessera_cli.embedded import free_port, redis_server, stop_processes

        self.redis_url = stack.enter_context(redis_server(workdir)).url
        self.redis = redis.Redis.from_url(self.redis_url)
        env = {k: v for k, v in os.environ.items() if not k.startswith("TESSERA_")}
        # No tokens: the benchmark's client is on the same host (loopback), as `tessera serve`.
        env.update(TESSERA_REDIS_URL=self.redis_url, REDIS_URL=self.redis_url, TESSERA_ALLOW_ANONYMOUS_LOOPBACK="1")
        port = free_port()
        self.base = f"http://127.0.0.1:{port}"
        self.procs: list[subprocess.Popen] = []
        stack.callback(lambda: stop_processes(self.procs, 30))
        self.procs.append(subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "--factory", "tessera_service.app:create_app",
             "--port", str(port), "--log-level", "warning"], env=env))
        self.env = env
        self.heartbeat_ttl = heartbeat_ttl
        self.workers = [self.add_worker(f"bench-{i}") for i in range(workers)]
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{self.base}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the API did not start")
            time.sleep(0.05)
        self.client = stack.enter_context(httpx.Client(base_url=self.base, timeout=600))

    def add_worker(self, name: str) -> subprocess.Popen:
        from tessera_queue import redis_schema as rdb

        proc = subprocess.Popen([sys.executable, "-m", "tessera_worker", "--name", name,
                                 "--threads", "1", "--heartbeat-ttl", str(self.heartbeat_ttl),
                                 "--log-level", "WARNING"], env=self.env)
        self.procs.append(proc)
        deadline = time.monotonic() + 60
        while not self.redis.exists(rdb.worker_key(name)):
            if time.monotonic() > deadline:
                raise RuntimeError(f"worker {name} did not start")
            time.sleep(0.05)
        time.sleep(1.0)  # its render process imports the renderer meanwhile
        return proc

    def submit(self, scene: Path = CORNELL, **form) -> str:
        with open(scene, "rb") as f:
            r = self.client.post("/jobs", files={"file": (scene.name, f)},
                                 data={k: str(v) for k, v in form.items()})
        r.raise_for_status()
        return r.json()["id"]

    def wait(self, job_id: str) -> dict:
        # Server-Sent Events, as `tessera submit --wait` does: no polling load on the
        # machine that is also rendering.
        with self.client.stream("GET", f"/jobs/{job_id}/events") as events:
            for _ in events.iter_lines():
                pass
        status = self.client.get(f"/jobs/{job_id}").json()
        if status["state"] != "done":
            raise RuntimeError(f"job {job_id}: {status}")
        return status

    def render(self, **form) -> tuple[float, dict]:
        """Wall time from upload to EXR downloaded."""
        start = time.perf_counter()
        job_id = self.submit(**form)
        status = self.wait(job_id)
        self.client.get(f"/jobs/{job_id}/image.exr").raise_for_status()
        return time.perf_counter() - start, status


def local_seconds(settings) -> float:
    from tessera_renderer import load_scene

    from tessera.local import render_image
    return render_image(load_scene(str(CORNELL)), settings, threads=2, progress=False).seconds


def efficiency(repeats: int, res: int, spp: int) -> dict:
    from tessera_base.protocol import RenderSettings

    settings = RenderSettings(width=res, height=res, spp=spp, seed=0)
    local, farm_t, ratio = [], [], []
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        farm = Farm(stack, tmp, workers=2)
        farm.render(width=16, height=16, spp=1)  # warm-up: pre-flight cached, scene loaded
        for i in range(repeats):
            l = local_seconds(settings)
            f, _ = farm.render(width=res, height=res, spp=spp, seed=0)
            local.append(l)
            farm_t.append(f)
            ratio.append(l / f)
            print(f"  efficiency repeat {i + 1}: local {l:.2f} s, farm {f:.2f} s, "
                  f"ratio {l / f:.3f}", flush=True)
    return {"local_seconds": summary(local), "farm_seconds": summary(farm_t),
            "efficiency": summary(ratio)}


def dispatch(repeats: int, tiles: int) -> dict:
    from tessera_queue import redis_schema as rdb

    side = 8 * int(tiles ** 0.5)
    per_tile, throughput = [], []
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        farm = Farm(stack, tmp, workers=1)
        farm.render(width=16, height=16, spp=1)
        for _ in range(repeats):
            wall, status = farm.render(width=side, height=side, spp=1, tile_size=8, max_depth=4)
            per_tile.append((wall - status["render_seconds"]) / status["tiles_total"] * 1000)
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        farm = Farm(stack, tmp, workers=2)
        farm.render(width=16, height=16, spp=1)
        side2 = 8 * int((4 * tiles) ** 0.5)
        for _ in range(repeats):
            job_id = farm.submit(width=side2, height=side2, spp=1, tile_size=8, max_depth=4)
            status = farm.wait(job_id)
            # From the first tile taken to the last stored, as the workers recorded them.
            started, finished = farm.redis.hmget(rdb.job_key(job_id), "started_at",
                                                 "finished_at")
            throughput.append(status["tiles_total"] / (float(finished) - float(started)))
    return {"dispatch_ms_per_tile": summary(per_tile), "tiles_per_second": summary(throughput),
            "tiles": tiles, "throughput_tiles": (8 * int((4 * tiles) ** 0.5) // 8) ** 2}


def recovery(repeats: int) -> dict:
    from tessera_queue import redis_schema as rdb

    seconds = []
    with ExitStack() as stack, tempfile.TemporaryDirectory() as tmp:
        farm = Farm(stack, tmp, workers=0, heartbeat_ttl=5.0)
        workers = {f"rec-{i}": farm.add_worker(f"rec-{i}") for i in range(2)}
        farm.render(width=16, height=16, spp=1)
        for i in range(repeats):
            job_id = farm.submit(width=64, height=64, spp=2048, tile_size=32, max_depth=16)
            queue = rdb.job_queue_key(job_id)
            victim = entry = None
            while victim is None:
                for name in workers:
                    held = farm.redis.xpending_range(queue, rdb.WORKER_GROUP, "-", "+", 1,
                                                     consumername=name)
                    if held:
                        victim, entry = name, held[0]
                        break
                time.sleep(0.005)
            workers[victim].send_signal(signal.SIGKILL)
            killed = time.perf_counter()
            workers.pop(victim).wait()
            entry_id = entry["message_id"]
            while True:
                owner = farm.redis.xpending_range(queue, rdb.WORKER_GROUP, entry_id,
                                                  entry_id, 1)
                if not owner or owner[0]["consumer"].decode() != victim:
                    break
                time.sleep(0.005)
            seconds.append(time.perf_counter() - killed)
            print(f"  recovery repeat {i + 1}: {seconds[-1]:.2f} s", flush=True)
            farm.client.delete(f"/jobs/{job_id}")
            workers[f"rec-new-{i}"] = farm.add_worker(f"rec-new-{i}")
    return {"recovery_seconds": summary(seconds), "heartbeat_ttl": 5.0, "reap_interval": 2.0}


def noise_target(repeats: int) -> dict:
    import numpy as np
    from tessera_renderer import load_scene

    from tessera.local import render_tile_passes
    from tessera_base import convergence
    from tessera_base.protocol import RenderSettings, tile_grid

    with tempfile.TemporaryDirectory() as tmp:
        far = Path(tmp, "cornell-far.usda")
        text = CORNELL.read_text()
        assert "(278, 273, -800)" in text
        far.write_text(text.replace("(278, 273, -800)", "(278, 273, -2400)"))
        scene = load_scene(str(far))
    res, tile = 128, 16
    adaptive = RenderSettings(width=res, height=res, seed=0, tile_size=tile, max_depth=16,
                              target_error=0.05, min_spp=16, max_spp=1024)
    grid = tile_grid(res, res, tile)

    def worst_error(spp_of_tile: dict[int, int]) -> float:
        """The worst tile error (the renderer's own variance estimate) at these counts."""
        worst = 0.0
        for t in grid:
            n = spp_of_tile[t.index]
            rgba, var = scene.render_tile(t.x0, t.y0, t.width, t.height, width=res, height=res,
                                          spp=n, seed=0, max_depth=16, threads=2,
                                          return_variance=True)
            worst = max(worst, convergence.tile_error(rgba, var, n))
        return worst

    times_a, times_f, ratio, used = [], [], [], {}
    for i in range(repeats):
        start = time.perf_counter()
        used = {t.index: render_tile_passes(scene, adaptive, t, threads=2)[1] for t in grid}
        ta = time.perf_counter() - start
        fixed = RenderSettings(width=res, height=res, seed=0, tile_size=tile, max_depth=16,
                               spp=max(used.values()))
        start = time.perf_counter()
        for t in grid:
            render_tile_passes(scene, fixed, t, threads=2)
        tf = time.perf_counter() - start
        times_a.append(ta)
        times_f.append(tf)
        ratio.append(tf / ta)
        print(f"  noise target repeat {i + 1}: to target {ta:.2f} s, fixed {fixed.spp} spp "
              f"{tf:.2f} s, saved x{tf / ta:.2f}", flush=True)
    fixed_spp = max(used.values())
    counts = np.array(list(used.values()))
    return {"adaptive_seconds": summary(times_a), "fixed_seconds": summary(times_f),
            "speedup": summary(ratio), "fixed_spp": fixed_spp,
            "mean_spp_adaptive": float(counts.mean()),
            "tiles_after_first_pass": int((counts == adaptive.min_spp).sum()),
            "tiles": len(grid), "target_error": adaptive.target_error,
            "worst_tile_error_adaptive": worst_error(used),
            "worst_tile_error_fixed": worst_error({k: fixed_spp for k in used})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="smaller images (a smoke run)")
    args = parser.parse_args()
    res, spp = (256, 16) if args.quick else (512, 64)
    load = os.getloadavg()[0]
    print("farm efficiency ...", flush=True)
    eff = efficiency(args.repeats, res, spp)
    print("dispatch overhead and throughput ...", flush=True)
    disp = dispatch(args.repeats, 256)
    print("dead-worker recovery ...", flush=True)
    rec = recovery(args.repeats)
    print("noise target ...", flush=True)
    noise = noise_target(args.repeats)
    result = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "cpus": os.cpu_count(), "load_at_start": load, "python": platform.python_version(),
              "image": {"res": res, "spp": spp, "tile_size": 64},
              "efficiency": eff, "dispatch": disp, "recovery": rec, "noise_target": noise}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "farm.json").write_text(json.dumps(result, indent=2) + "\n")
    md = f"""# Farm benchmark

Written by `benchmarks/farm.py` on {result['date']}; {result['cpus']} CPUs (shared with other
work: load average {load:.2f} at start). Medians ± half-range over {args.repeats} repeats; each ratio
is formed per repeat pair, so that both sides of a ratio saw the same machine load.

| quantity | value |
|---|---|
| local render, Cornell {res}x{res} {spp} spp, 2 threads | {fmt(eff['local_seconds'], ' s')} |
| farm, 2 workers x 1 thread, upload → EXR downloaded | {fmt(eff['farm_seconds'], ' s')} |
| **farm efficiency** = local / farm (target ≥ 0.95) | **{fmt(eff['efficiency'])}** |
| per-tile dispatch overhead (1 worker, {disp['tiles']} tiles of 8x8, 1 spp) | {fmt(disp['dispatch_ms_per_tile'], ' ms')} |
| queue throughput (2 workers, {disp['throughput_tiles']} tiles of 8x8, 1 spp) | {fmt(disp['tiles_per_second'], ' tiles/s')} |
| dead worker's tile reclaimed after SIGKILL (heartbeat TTL 5 s, reap every 2 s) | {fmt(rec['recovery_seconds'], ' s')} |
| noise target {noise['target_error']:.0%}: time of fixed {noise['fixed_spp']} spp / time to target | **{fmt(noise['speedup'])}** |
| noise target: mean spp, tiles done after the first pass | {noise['mean_spp_adaptive']:.0f} spp; {noise['tiles_after_first_pass']} of {noise['tiles']} tiles |
| worst tile error: noise target / fixed spp | {noise['worst_tile_error_adaptive']:.3f} / {noise['worst_tile_error_fixed']:.3f} |

The noise-target scene is the Cornell box seen from 2.4 m further back (128x128, tiles of
16): the black surround converges after its first pass of 16 samples; the box's tiles
need up to {noise['fixed_spp']} samples. The fixed-spp render uses that many everywhere, so both
images have the same worst tile error (the renderer's own variance estimate).
"""
    (OUT / "farm.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
