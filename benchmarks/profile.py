"""Where a render spends its time: `perf record` of one render, the top symbols and libraries.

    .venv/bin/python benchmarks/profile.py [--label current] [--core OLD.so] [--integrator path]
                                           [--scene cornell] [--spp 16] [--top 20]

Renders `--scene` (a `tessera bench` scene name) at 256x256 on 2 threads under
`perf record` (sampling at 999 Hz, no call graphs) and keeps perf's flat profile: the share
of samples per shared library and the top symbols by self time. The whole child process is
sampled, so Python start-up and the scene load are in the profile too (the
`libpython`/`ld-linux` rows); the renderer's share is `_core`, Embree's `libembree3`.
`--core` profiles another build's `_core*.so` (the one before an optimisation), so the
before and after can be recorded on the same machine. Each run replaces its label's
section of docs/benchmarks/profile.json and regenerates profile.md from all sections.
perf comes from Debian (`linux-perf`); scripts/setup.sh does not install it.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

from common import LOAD_CORE, OUT, REPO

CHILD = LOAD_CORE + r"""
import time
import numpy as np
name, integ, spp = sys.argv[2], sys.argv[3], int(sys.argv[4])
from tessera_tools.bench import SCENES, load_bench_scene
sc = load_bench_scene(SCENES[name])
splats = np.zeros((256, 256, 3), np.int64) if integ in ("bdpt", "light") else None
t = time.perf_counter()
sc.render_tile(0, 0, 256, 256, width=256, height=256, spp=spp, seed=1, threads=2, integrator=integ, splats=splats)
print(time.perf_counter() - t)
"""

ROW = re.compile(r"^\s*([0-9.]+)%\s+(\S+)\s+\[\.\]\s+(.+?)(?:\s+-\s+-)?\s*$")
DSO_ROW = re.compile(r"^\s*([0-9.]+)%\s+(\S+)\s*$")


def perf_report(data: str, sort: str) -> list[str]:
    out = subprocess.run(["perf", "report", "-i", data, "--stdio", "--no-children", "-g", "none", "--sort", sort],
                         capture_output=True, text=True, check=True).stdout
    return [ln for ln in out.splitlines() if ln.strip() and not ln.startswith("#")]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--label", default="current")
    ap.add_argument("--core", default="", help="a _core*.so of another build")
    ap.add_argument("--integrator", default="path")
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--top", type=int, default=20)
    args = ap.parse_args()
    if not shutil.which("perf"):
        print("perf is not installed (apt-get install linux-perf)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="tessera-profile-") as tmp:
        data = os.path.join(tmp, "perf.data")
        core = os.path.abspath(args.core) if args.core else ""
        run = subprocess.run(["perf", "record", "-F", "999", "-o", data, "--", sys.executable, "-c", CHILD, core,
                              args.scene, args.integrator, str(args.spp)],
                             capture_output=True, text=True, cwd=REPO, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
        if run.returncode != 0:
            print(run.stderr, file=sys.stderr)
            return 1
        seconds = float(run.stdout.strip().splitlines()[-1])
        symbols = []
        for ln in perf_report(data, "dso,symbol"):
            m = ROW.match(ln)
            if m:
                symbols.append({"percent": float(m.group(1)), "dso": m.group(2), "symbol": m.group(3)})
        dsos = []
        for ln in perf_report(data, "dso"):
            m = DSO_ROW.match(ln)
            if m:
                dsos.append({"percent": float(m.group(1)), "dso": m.group(2)})
    path = OUT / "profile.json"
    allp = json.loads(path.read_text()) if path.is_file() else {}
    allp[args.label] = {"scene": args.scene, "integrator": args.integrator, "spp": args.spp, "res": 256,
                        "render_seconds": seconds, "core": os.path.basename(args.core) if args.core else "this tree",
                        "dsos": dsos[:8], "symbols": symbols[:args.top]}
    OUT.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(allp, indent=2) + "\n")
    lines = ["# Profiles", "", "Written by `benchmarks/profile.py`: `perf record` (999 Hz, flat) of one render of a "
             "`tessera bench` scene at 256x256 on 2 threads; the whole process is sampled, so Python start-up and "
             "the scene load are included (`libpython`, `ld-linux`). Self time per symbol; inlined functions "
             "count toward their caller. One section per label (re-run with the same label to replace it).", ""]
    for label, p in allp.items():
        lines += [f"## {label}", "", f"{p['scene']}, `{p['integrator']}`, {p['spp']} spp, renderer build: "
                  f"{p['core']}; render call {p['render_seconds']:.2f} s (under perf).", "",
                  "Libraries: " + ", ".join(f"{d['dso']} {d['percent']:.1f} %" for d in p["dsos"][:5]), "",
                  "| % samples | library | symbol |", "|---|---|---|"]
        lines += [f"| {s['percent']:.2f} | {s['dso']} | `{s['symbol']}` |" for s in p["symbols"]]
        lines.append("")
    (OUT / "profile.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
