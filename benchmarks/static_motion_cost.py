"""What motion-blur support costs a scene that does not move: the renderer as it is against
the renderer before motion blur existed, on static scenes, in the same run.

    .venv/bin/python benchmarks/static_motion_cost.py [--repeats 5] [--baseline ef27171]

The baseline is the last commit before the core learned motion (ef27171: no ray times,
no time steps, no per-sample instant). Its renderer package and `_core` module are built
once into build/bench-static/ (a git worktree and a CMake Release build with the same
flags as the package's). Both sides are then copied into their own directory and run the
same way: a fresh child process per measurement, importing `tessera_renderer` from that
directory only, loading the scene, rendering a warm-up tile, then timing one render of
the whole image. Sides alternate within each repeat (A B B A ...), and the ratio is
taken per repeat (median ± half-range over repeats).

Scenes: the Cornell box example (world mesh, path 128 x 128 at 64 spp; bdpt at 16 spp),
and a static instanced scene (one ~100k-triangle prototype placed by 64 instances, path
96 x 64 at 512 spp), which runs the instance paths that moving instances changed.

Results go to docs/benchmarks/static-motion.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

from common import CORNELL, OUT, REPO, summary
from shapes import child_env

WORK = REPO / "build" / "bench-static"

_CHILD = r"""
import importlib.abc, json, sys, time
# Only this side's package: drop the editable install's finder that maps tessera_renderer
# to the working tree.
sys.meta_path = [f for f in sys.meta_path if "editable" not in type(f).__module__.lower()
                 and "skbc" not in type(f).__module__.lower()]
sys.path.insert(0, sys.argv[1])
import numpy as np
import tessera_renderer
assert tessera_renderer.__file__.startswith(sys.argv[1]), tessera_renderer.__file__
from tessera_renderer import _core, load_scene
from shapes import wavy_grid

case = sys.argv[2]

def instanced():
    pts, tris = wavy_grid()
    mats = []
    for k in range(64):
        ang = np.radians(20.0 * k)
        m = np.eye(4, dtype=np.float32)
        m[:3, :3] = [[np.cos(ang), 0, -np.sin(ang)], [0, 1, 0], [np.sin(ang), 0, np.cos(ang)]]
        m[3, :3] = (3.0 * (k % 8), 0.0, -3.0 * (k // 8))
        mats.append(m)
    z3 = np.zeros((0, 3), np.float32)
    scene = _core.Scene(z3, np.zeros((0, 3), np.uint32), np.zeros(0, np.uint32),
                        np.array([[0.7, 0.7, 0.7]], np.float32), np.zeros((1, 3), np.float32),
                        np.zeros(1, bool), np.zeros((0, 7), np.float32), np.zeros((0, 6), np.float32),
                        np.array([[0.3, -1.0, -0.2, 0.05, 3.0, 3.0, 3.0]], np.float32), (0.2, 0.2, 0.2),
                        prototypes=[(pts, tris, np.zeros(len(tris), np.uint32), None, None)],
                        instance_prototype=np.zeros(64, np.uint32), instance_transforms=np.array(mats))
    cam = _core.Camera((10.5, 6.0, 8.0), (1, 0, 0), (0, 0.8, -0.6), (0, -0.6, -0.8), 0.8, 0.55, 96, 64)
    def run(spp):
        t = time.perf_counter()
        rgba, _ = _core.render_tile(scene, cam, 0, 0, 96, 64, spp, 0, 8, 2, 0, False, "path", None, "sobol", [],
                                    {}, None)
        return time.perf_counter() - t, rgba
    return run

if case == "instanced":
    run = instanced()
    run(2)
    seconds, rgba = run(512)
    print(json.dumps({"seconds": seconds, "checksum": float(np.asarray(rgba, np.float64).sum())}))
else:
    integrator, spp = case.split(":")
    scene = load_scene(sys.argv[3])
    splats = lambda: np.zeros((128, 128, 3), np.int64)  # light and bdpt splat across the image
    scene.render_tile(0, 0, 128, 128, width=128, height=128, spp=2, threads=2, integrator=integrator,
                      splats=splats())
    t = time.perf_counter()
    out = scene.render_tile(0, 0, 128, 128, width=128, height=128, spp=int(spp), threads=2, integrator=integrator,
                            splats=splats())
    seconds = time.perf_counter() - t
    rgba = out[0] if isinstance(out, tuple) else out
    print(json.dumps({"seconds": seconds, "checksum": float(np.asarray(rgba, np.float64).sum())}))
"""

CASES = {"cornell path 64 spp": "path:64", "cornell bdpt 16 spp": "bdpt:16", "instanced path 512 spp": "instanced"}


def _run(cmd, **kw):
    subprocess.run(cmd, check=True, **kw)


def prepare_side(name: str, source: Path, build: Path) -> Path:
    """The side's package directory: its tessera_renderer with its own _core module."""
    _run(["cmake", "-S", str(source), "-B", str(build), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
          "-DTESSERA_BUILD_TESTS=OFF", "-DSKBUILD=ON", f"-DPython_EXECUTABLE={sys.executable}"],
         stdout=subprocess.DEVNULL)
    _run(["cmake", "--build", str(build), "--target", "_core", "_subdivision", "-j", str(os.cpu_count() or 2)],
         stdout=subprocess.DEVNULL)
    pkg = WORK / name / "pkg"
    shutil.rmtree(pkg, ignore_errors=True)
    shutil.copytree(source / "renderer" / "tessera_renderer", pkg / "tessera_renderer",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    for so in (build / "renderer").glob("_*.so"):
        shutil.copy2(so, pkg / "tessera_renderer" / so.name)
    return pkg


def baseline_source(commit: str) -> Path:
    src = WORK / "baseline-src"
    if not src.exists():
        _run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(src), commit], stdout=subprocess.DEVNULL)
    else:
        _run(["git", "-C", str(src), "checkout", "--detach", "-q", commit])
    return src


def measure(pkg: Path, case: str) -> tuple[float, float]:
    r = subprocess.run([sys.executable, "-c", _CHILD, str(pkg), case, str(CORNELL)],
                       capture_output=True, text=True, cwd=WORK, env=child_env())
    if r.returncode != 0:
        sys.exit(f"{pkg.parent.name} {case} failed:\n{r.stderr[-3000:]}")
    got = json.loads(r.stdout.strip().splitlines()[-1])
    return got["seconds"], got["checksum"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline", default="ef27171", help="the commit before motion blur (default ef27171)")
    args = ap.parse_args()
    WORK.mkdir(parents=True, exist_ok=True)
    base_commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.baseline], check=True,
                                 capture_output=True, text=True).stdout.strip()
    head = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], check=True,
                          capture_output=True, text=True).stdout.strip()
    print(f"building the baseline {base_commit} and the candidate {head} (Release, _core only)", flush=True)
    sides = {"baseline": prepare_side("baseline", baseline_source(args.baseline), WORK / "baseline-build"),
             "candidate": prepare_side("candidate", REPO, WORK / "candidate-build")}
    load_before = os.getloadavg()[0]
    times = {c: {s: [] for s in sides} for c in CASES}
    ratios = {c: [] for c in CASES}
    for r in range(args.repeats):
        order = list(sides) if r % 2 == 0 else list(sides)[::-1]
        for label, case in CASES.items():
            measured = {s: measure(sides[s], case) for s in order}
            # The same scene, samples and sample streams: the same image, to the bit.
            if measured["baseline"][1] != measured["candidate"][1]:
                sys.exit(f"{label}: the two renderers' images differ ({measured})")
            got = {s: m[0] for s, m in measured.items()}
            for s, v in got.items():
                times[label][s].append(v)
            ratios[label].append(got["candidate"] / got["baseline"])
            print(f"repeat {r + 1}: {label}: baseline {got['baseline']:.3f} s, candidate {got['candidate']:.3f} s, "
                  f"ratio {ratios[label][-1]:.3f}", flush=True)
    load_after = os.getloadavg()[0]
    result = {"baseline": base_commit, "candidate": head, "repeats": args.repeats,
              "machine": f"{platform.platform()} ({os.cpu_count()} CPUs)", "load": [load_before, load_after],
              "cases": {c: {"baseline": summary(times[c]["baseline"]), "candidate": summary(times[c]["candidate"]),
                            "ratio": summary(ratios[c])} for c in CASES}}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "static-motion.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = ["# Static scenes and motion-blur support", "",
             f"Measured by `benchmarks/static_motion_cost.py` on {result['machine']} (1-minute load average "
             f"{load_before:.1f} before, {load_after:.1f} after): the renderer at {head} (motion blur compiled "
             f"in) against {base_commit} (before the core had ray times, time steps or a per-sample instant), "
             f"both built Release with the same flags, on scenes that do not move. Each measurement a fresh "
             f"process (scene load and a warm-up tile not timed), the two images checked equal (pixel "
             f"sums identical); sides alternate within each of "
             f"{args.repeats} repeats; ratio = candidate / baseline per repeat, median ± half-range.", "",
             "| scene | baseline | candidate | candidate / baseline |", "|---|---|---|---|"]
    for c in CASES:
        b, k, q = (result["cases"][c][x] for x in ("baseline", "candidate", "ratio"))
        lines.append(f"| {c} | {b['median']:.3f} s ± {b['half_range']:.3f} | {k['median']:.3f} s ± "
                     f"{k['half_range']:.3f} | {q['median']:.3f} ± {q['half_range']:.3f} |")
    (OUT / "static-motion.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
