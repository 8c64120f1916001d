"""`auto` by measurement: what the pilot chooses, against time to relMSE 1e-2 measured by
`tessera bench`.

    .venv/bin/python benchmarks/auto_pilot.py [--reps 3]

For each scene the pilot (tessera/tessera/pilot.py) runs `--reps` times for a render of the
bench's own settings (64 x 64, passes of 1, 1, 2, ... up to 256 samples, so merging
integrators are candidates where the scene has mirrors or glass); the check is which of
its candidates reached relMSE 1e-2 first in the bench's runs: docs/benchmarks/caustics/
(benchmarks/caustics.py: the caustic and the mirror scene, all five integrators, Mitsuba
beside) and docs/benchmarks/error-vs-time.json (`tessera bench`: the Cornell box, path and
bdpt). Writes docs/benchmarks/auto.{md,json}. The handicaps of the merging candidates
are in the JSON rows.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np
from common import OUT, REPO

SCENES = {"cornell": (REPO / "examples" / "cornell" / "cornell.usda", OUT / "error-vs-time.json"),
          "caustic": (REPO / "examples" / "caustic" / "caustic.usda", OUT / "caustics" / "error-vs-time.json"),
          "caustic-mirror": (REPO / "examples" / "caustic" / "caustic_mirror.usda",
                             OUT / "caustics" / "error-vs-time.json")}


def bench_times(name: str, results) -> dict[str, float]:
    """Median seconds to relMSE 1e-2 of each Tessera integrator in the bench's results."""
    if not results.is_file():
        return {}
    series = json.loads(results.read_text())["scenes"].get(name, {}).get("series", {})
    return {s["integrator"]: s["time_to_0.01"]["median"] for s in series.values()
            if s["renderer"] == "tessera" and "time_to_0.01" in s}


def main() -> int:
    from tessera.pilot import run_pilot
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args()
    # A noise target of 0.1 is relMSE 1e-2, the bench's first target.
    settings = RenderSettings(width=64, height=64, target_error=0.1, min_spp=1, max_spp=256)
    result = {"load_average": os.getloadavg()[0], "settings": settings.model_dump(mode="json"), "scenes": {}}
    lines = ["# `auto` by measurement: the pilot's choice", "",
             "Written by `benchmarks/auto_pilot.py`. The pilot (4 x 4 spp of each candidate at 64 px, efficiency = "
             "handicap / (relative variance x seconds at the render's size), tessera/tessera/pilot.py) runs "
             f"{args.reps} times per scene for a render of the bench's settings: 64 x 64, passes of 1, 1, 2, ... "
             "up to 256 samples, noise target 0.1 (relMSE 1e-2), so a merging integrator's handicap is "
             "(v / 1e-2)^(1 - 1/alpha). The check is the bench's time to relMSE 1e-2 among the same candidates "
             "(docs/benchmarks/caustics/ for the caustic scenes, docs/benchmarks/error-vs-time.json for the "
             "Cornell box). 2 threads.", "",
             "Each run has its own pilot seeds.", "",
             "| scene | candidates | pilot choices | pilot seconds | pilot efficiency (median of runs) | typical "
             "efficiency | bench: seconds to relMSE 1e-2 | fastest by the bench |", "|---|---|---|---|---|---|---|---|"]
    agree = 0
    for name, (path, bench) in SCENES.items():
        scene = load_scene(path)
        pilots = []
        for rep in range(args.reps):  # each run its own pilot seeds: the rare hits differ
            t = time.perf_counter()
            p = run_pilot(scene, settings, threads=2, seed=0x51107 + 1000 * rep)
            pilots.append({"choice": p.choice, "seconds": time.perf_counter() - t,
                           "rows": [r.__dict__ for r in p.rows]})
        names = [r["integrator"] for r in pilots[0]["rows"]]
        def median_of(field):
            return {c: float(np.median([next(r[field] for r in p["rows"] if r["integrator"] == c)
                                        for p in pilots])) for c in names}
        eff, typical = median_of("efficiency"), median_of("typical_efficiency")
        times = {c: t for c, t in bench_times(name, bench).items() if c in names}
        best = min(times, key=times.get) if times else "—"
        agree += sum(p["choice"] == best for p in pilots)
        result["scenes"][name] = {"pilots": pilots, "bench_seconds_to_1e-2": times, "bench_fastest": best}
        lines.append(f"| {name} | {', '.join(names)} | {', '.join(p['choice'] for p in pilots)} | "
                     f"{np.median([p['seconds'] for p in pilots]):.2f} | "
                     f"{', '.join(f'{c} {e:.3g}' for c, e in eff.items())} | "
                     f"{', '.join(f'{c} {e:.3g}' for c, e in typical.items())} | "
                     f"{', '.join(f'{c} {t:.3g}' for c, t in times.items())} | {best} |")
        print(lines[-1], flush=True)
    lines += ["", f"The pilot's choice is the bench's fastest in {agree} of {args.reps * len(SCENES)} runs.", "",
              f"Load average at the start: {result['load_average']:.2f} (2 shared vCPUs)."]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "auto.json").write_text(json.dumps(result, indent=2) + "\n")
    (OUT / "auto.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
