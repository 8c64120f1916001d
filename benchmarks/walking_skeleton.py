"""Walking-skeleton benchmark: the numbers the closing note reports, measured in one run.

    .venv/bin/python benchmarks/walking_skeleton.py [--repeats 5] [--skip-build] [--skip-tests]

1. Clean build time: a wheel built from scratch in an empty build directory.
2. Test-suite time: ctest + pytest, as scripts/test.sh runs them (set-up excluded).
3. Path-tracer throughput: Cornell box, 512x512, 2 threads, samples per second.
4. Farm overhead: wall time of the same image on the embedded farm (private Redis, two
   1-thread workers, HTTP submit -> done -> EXR downloaded) divided by the local render with
   2 threads. Local and farm runs alternate so that drift in machine load hits both alike.

Every figure is the median of its repeats, with the half-range of those repeats as its
error (min..max). Ratios are formed per repeat pair. Results go to
docs/benchmarks/walking-skeleton.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time

import httpx
from common import CORNELL, OUT, REPO, fmt, summary


def clean_build_seconds() -> float:
    with tempfile.TemporaryDirectory() as build, tempfile.TemporaryDirectory() as wheels:
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                        "-w", wheels, "-C", f"build-dir={build}", str(REPO)], check=True)
        return time.perf_counter() - start


def test_suite_seconds() -> dict:
    build_dir = max((p for p in (REPO / "build").iterdir() if (p / "CTestTestfile.cmake").exists()),
                    key=lambda p: p.stat().st_mtime)
    t0 = time.perf_counter()
    subprocess.run(["ctest", "--test-dir", str(build_dir)], check=True, stdout=subprocess.DEVNULL)
    t1 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=REPO, check=True,
                   stdout=subprocess.DEVNULL)
    t2 = time.perf_counter()
    return {"ctest": t1 - t0, "pytest": t2 - t1, "total": t2 - t0}


def local_render(spp: int, res: int) -> float:
    from tessera_renderer import load_scene

    from tessera.local import render_image
    from tessera_base.protocol import RenderSettings

    scene = load_scene(CORNELL)
    settings = RenderSettings(width=res, height=res, spp=spp, seed=0, tile_size=64)
    return render_image(scene, settings, threads=2, progress=False).seconds


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class EmbeddedFarm:
    """`tessera serve` in its embedded mode: private redis-server + 2 local workers."""

    def __init__(self, workers: int = 2):
        self.port = free_port()
        env = {k: v for k, v in os.environ.items() if k != "REDIS_URL"}
        self.proc = subprocess.Popen([sys.executable, "-m", "tessera", "serve", "--port", str(self.port),
                                      "--workers", str(workers), "--worker-threads", "1"],
                                     env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.url = f"http://127.0.0.1:{self.port}"
        deadline = time.time() + 60
        while time.time() < deadline:
            try:
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.close()
        raise RuntimeError("embedded farm did not start")

    def render(self, spp: int, res: int) -> float:
        start = time.perf_counter()
        with open(CORNELL, "rb") as f:
            r = httpx.post(self.url + "/jobs", files={"file": ("cornell.usda", f)},
                           data={"spp": spp, "width": res, "height": res, "tile_size": 64, "seed": 0},
                           timeout=60)
        r.raise_for_status()
        job = r.json()["id"]
        while True:
            state = httpx.get(f"{self.url}/jobs/{job}", timeout=10).json()["state"]
            if state == "done":
                break
            if state in ("failed", "cancelled"):
                raise RuntimeError(f"farm job {state}")
            # A client polling at 4 Hz; faster polling steals render time from the 2 cores.
            time.sleep(0.25)
        httpx.get(f"{self.url}/jobs/{job}/image.exr", timeout=60).raise_for_status()
        return time.perf_counter() - start

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--skip-build", action="store_true")
    ap.add_argument("--skip-tests", action="store_true")
    args = ap.parse_args()

    results: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                 "load_average_at_start": os.getloadavg()},
                     "settings": {"scene": "examples/cornell/cornell.usda", "res": args.res, "spp": args.spp,
                                  "repeats": args.repeats}}
    if not args.skip_build:
        print("clean build ...", flush=True)
        results["clean_build_seconds"] = clean_build_seconds()
    if not args.skip_tests:
        print("test suite ...", flush=True)
        results["test_suite_seconds"] = test_suite_seconds()

    print("local vs farm ...", flush=True)
    local_render(4, 64)  # warm-up: imports, first BVH build
    farm = EmbeddedFarm(workers=2)
    try:
        farm.render(4, 64)  # warm-up: workers import the renderer and cache the scene
        local, remote = [], []
        for i in range(args.repeats):
            local.append(local_render(args.spp, args.res))
            remote.append(farm.render(args.spp, args.res))
            print(f"  repeat {i + 1}: local {local[-1]:.2f} s, farm {remote[-1]:.2f} s", flush=True)
    finally:
        farm.close()
    samples = args.res * args.res * args.spp
    results["local_seconds"] = summary(local)
    results["farm_seconds"] = summary(remote)
    results["samples_per_second_2_threads"] = summary([samples / t for t in local])
    results["farm_overhead_ratio"] = summary([r / l for r, l in zip(remote, local)])

    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "walking-skeleton.json").write_text(json.dumps(results, indent=2) + "\n")
    lines = [
        "# Walking skeleton benchmark",
        "",
        f"Written by `benchmarks/walking_skeleton.py` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
        f"{os.cpu_count()} CPUs, load average at start {results['machine']['load_average_at_start'][0]:.2f}.",
        f"Scene: Cornell box, {args.res}x{args.res}, {args.spp} spp. Medians ± half-range over the repeats.",
        "",
        "| quantity | value |",
        "|---|---|",
    ]
    if "clean_build_seconds" in results:
        lines.append(f"| clean build (pip wheel, empty build dir) | {results['clean_build_seconds']:.1f} s |")
    if "test_suite_seconds" in results:
        t = results["test_suite_seconds"]
        lines.append(f"| test suite (ctest + pytest, no set-up) | {t['total']:.1f} s "
                     f"(ctest {t['ctest']:.1f} s, pytest {t['pytest']:.1f} s) |")
    lines += [
        f"| path tracer, 2 threads | {fmt({k: (v / 1e6 if isinstance(v, float) else v) for k, v in results['samples_per_second_2_threads'].items() if k != 'values'} | {'n': args.repeats}, ' M samples/s')} |",
        f"| local render wall time (2 threads) | {fmt(results['local_seconds'], ' s')} |",
        f"| farm wall time (2 workers x 1 thread, HTTP submit to EXR downloaded) | {fmt(results['farm_seconds'], ' s')} |",
        f"| farm overhead = farm / local | {fmt(results['farm_overhead_ratio'])} |",
    ]
    (OUT / "walking-skeleton.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
