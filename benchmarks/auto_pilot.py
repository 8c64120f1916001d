"""`auto` by measurement: what the pilot chooses, against time to relMSE 1e-2 and 1e-3
measured by `tessera bench`.

    .venv/bin/python benchmarks/auto_pilot.py [--reps 3]

For each scene and each of the two noise targets (0.1 and 0.0316: relMSE 1e-2 and 1e-3)
the pilot (tessera/tessera/pilot.py) runs `--reps` times for a render of the bench's own
settings (64 x 64, passes of 1, 1, 2, ... up to 4096 samples, so merging integrators are
candidates where the scene has mirrors or glass); the check is which of its candidates
reached that relMSE first in the bench's runs: docs/benchmarks/caustics/
(benchmarks/caustics.py: the caustic and the mirror scene, all five integrators, Mitsuba
beside) and docs/benchmarks/error-vs-time/error-vs-time.json (`tessera bench`: the Cornell box, path and
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

SCENES = {"cornell": (REPO / "examples" / "cornell" / "cornell.usda", OUT / "error-vs-time" / "error-vs-time.json"),
          "caustic": (REPO / "examples" / "caustic" / "caustic.usda", OUT / "caustics" / "error-vs-time.json"),
          "caustic-mirror": (REPO / "examples" / "caustic" / "caustic_mirror.usda",
                             OUT / "caustics" / "error-vs-time.json")}


TARGETS = {0.1: "0.01", 0.0316: "0.001"}   # noise target -> the bench's relMSE target


def bench_times(name: str, results, target: str) -> dict[str, tuple[float, str]]:
    """Median seconds to relMSE `target` of each Tessera integrator in the bench's results,
    with how they were read (interpolated or extrapolated)."""
    if not results.is_file():
        return {}
    series = json.loads(results.read_text())["scenes"].get(name, {}).get("series", {})
    return {s["integrator"]: (s[f"time_to_{target}"]["median"], s[f"time_to_{target}"]["how"])
            for s in series.values() if s["renderer"] == "tessera" and f"time_to_{target}" in s}


def main() -> int:
    from tessera.pilot import run_pilot
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args()
    settings = RenderSettings(width=64, height=64, target_error=0.1, min_spp=1, max_spp=4096)
    result = {"load_average": os.getloadavg()[0], "settings": settings.model_dump(mode="json"), "runs": []}
    lines = ["# `auto` by measurement: the pilot's choice", "",
             "Written by `benchmarks/auto_pilot.py`. The pilot (4 x 4 spp of each candidate at 64 px, efficiency = "
             "handicap / (relative variance x seconds at the render's size), tessera/tessera/pilot.py) runs "
             f"{args.reps} times per scene and noise target for a render of the bench's settings: 64 x 64, passes "
             "of 1, 1, 2, ... up to 4096 samples. A noise target e is relMSE e^2; a merging integrator's handicap "
             "is (v / e^2)^(1 - 1/alpha). The check is the bench's time to that relMSE among the same candidates "
             "(docs/benchmarks/caustics/ for the caustic scenes, docs/benchmarks/error-vs-time/error-vs-time.json for the "
             "Cornell box; its 1e-3 times are extrapolated), and the cost of the pilot's choice: the bench's time "
             "of the chosen integrator over the fastest's. 2 threads.", "",
             "Each run has its own pilot seeds.", "",
             "| scene | noise target (relMSE) | candidates | pilot choices | pilot seconds | pilot efficiency "
             "(median of runs) | typical efficiency | bench: seconds to the relMSE | fastest by the bench | "
             "time of the choices / fastest's |", "|---|---|---|---|---|---|---|---|---|---|"]
    agree, total = 0, 0
    for name, (path, bench) in SCENES.items():
        scene = load_scene(path)
        for target_error, rel in TARGETS.items():
            st = settings.model_copy(update={"target_error": target_error})
            pilots = []
            for rep in range(args.reps):  # each run its own pilot seeds: the rare hits differ
                t = time.perf_counter()
                p = run_pilot(scene, st, threads=2, seed=0x51107 + 1000 * rep)
                pilots.append({"choice": p.choice, "seconds": time.perf_counter() - t,
                               "rows": [r.__dict__ for r in p.rows]})
            names = [r["integrator"] for r in pilots[0]["rows"]]

            def median_of(field):
                return {c: float(np.median([next(r[field] for r in p["rows"] if r["integrator"] == c)
                                            for p in pilots])) for c in names}
            eff, typical = median_of("efficiency"), median_of("typical_efficiency")
            times = {c: t for c, t in bench_times(name, bench, rel).items() if c in names}
            best = min(times, key=lambda c: times[c][0]) if times else "—"
            cost = [times[p["choice"]][0] / times[best][0] for p in pilots if times]
            agree += sum(p["choice"] == best for p in pilots)
            total += len(pilots)
            result["runs"].append({"scene": name, "target_error": target_error, "rel_mse": float(rel),
                                   "pilots": pilots, "bench_seconds": times, "bench_fastest": best,
                                   "cost_of_choice": cost})
            lines.append(f"| {name} | {target_error:g} ({rel}) | {', '.join(names)} | "
                         f"{', '.join(p['choice'] for p in pilots)} | "
                         f"{np.median([p['seconds'] for p in pilots]):.2f} | "
                         f"{', '.join(f'{c} {e:.3g}' for c, e in eff.items())} | "
                         f"{', '.join(f'{c} {e:.3g}' for c, e in typical.items())} | "
                         f"{', '.join(f'{c} {t:.3g}' + ('' if how == 'interpolated' else ' (extrap.)') for c, (t, how) in times.items())} | "
                         f"{best} | {', '.join(f'{x:.2f}' for x in cost)} |")
            print(lines[-1], flush=True)
    lines += ["", f"The pilot's choice is the bench's fastest in {agree} of {total} runs.", "",
              f"Load average at the start: {result['load_average']:.2f} (2 shared vCPUs)."]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "auto.json").write_text(json.dumps(result, indent=2) + "\n")
    (OUT / "auto.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
