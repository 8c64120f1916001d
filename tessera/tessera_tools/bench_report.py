"""The bench's outputs: the CSV of every measurement, log-log plots and the markdown
summary (docs/benchmarks/error-vs-time.md)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .bench_stats import TARGETS, fmt


def _write_csv(path: Path, rows) -> None:
    fields = ["scene", "renderer", "integrator", "spp", "rep", "seed", "res", "seconds", "rel_mse", "rel_mse_raw", "rmse"]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in fields if k in r})


def _plots(result, rows, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    budget = result["config"]["budget_seconds"]
    for name, info in result["scenes"].items():
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
        for k, (label, s) in enumerate(info["series"].items()):
            color = f"C{k}"
            pts = [r for r in rows if r["scene"] == name and f"{r['renderer']} {r['integrator']}" == label]
            secs = np.array([r["seconds"] for r in pts])
            for ax, key in ((axes[0], "rel_mse"), (axes[1], "rmse")):
                vals = np.array([r[key] for r in pts])
                # A relMSE with the reference's own subtracted can fall to or below zero.
                keep = vals > 0
                ax.loglog(secs[keep], vals[keep], "o", color=color, ms=3.5, alpha=0.6,
                          label=label if key == "rmse" else None)
                x = np.log10(secs[keep])
                b, a = np.polyfit(x, np.log10(vals[keep]), 1)
                xs = np.linspace(x.min() - 0.3, x.max() + 0.5, 20)
                ax.loglog(10 ** xs, 10 ** (a + b * xs), "-", color=color, lw=1.2,
                          label=f"{label} (slope {b:.2f})" if key == "rel_mse" else None)
        scene_rows = [r for r in rows if r["scene"] == name]
        for ax, key in ((axes[0], "rel_mse"), (axes[1], "rmse")):
            vals = [r[key] for r in scene_rows if r[key] > 0] + (list(TARGETS) if key == "rel_mse" else [])
            ax.set_ylim(min(vals) / 3, max(vals) * 3)
            secs = [r["seconds"] for r in scene_rows] + [budget]
            ax.set_xlim(min(secs) / 2, max(secs) * 4)
        for t in TARGETS:
            axes[0].axhline(t, color="grey", ls="--", lw=0.8)
        axes[0].axvline(budget, color="grey", ls=":", lw=0.8)
        axes[0].set_ylabel("relMSE")
        axes[1].set_ylabel("RMSE")
        for ax in axes:
            ax.set_xlabel("seconds (wall clock, 2 threads)")
            ax.grid(True, which="both", alpha=0.25)
        axes[0].legend(fontsize=7)
        axes[1].legend(fontsize=7)
        fig.suptitle(f"{name}: error vs time, {info['res']}x{info['res']} "
                     f"(reference {info['reference']['integrator']} 2 x {info['reference']['spp']} spp)", fontsize=10)
        fig.tight_layout()
        fig.savefig(out / f"error-vs-time-{name}.png", dpi=90)
        plt.close(fig)


def _markdown(result) -> str:
    cfg = result["config"]
    L = ["# Error versus time: results", "",
         f"Written by `tessera bench` ({result['tessera']}) on {result['started']}: "
         f"{cfg['res']}x{cfg['res']} px, {cfg['threads']} threads, {cfg['reps']} interleaved repetitions, "
         f"max depth {cfg['max_depth']}. Values are median ± half-range over the repetitions: a time "
         "to a target inside a repetition's measured range is read between its two bracketing points "
         "(interpolated), outside it off that repetition's log-log fit (relMSE = a · seconds^slope; "
         "extrapolated). relMSE has the reference's own subtracted. Raw points: `error-vs-time.csv`; everything: "
         "`error-vs-time.json`. How to read it: `error-vs-time.md`.", ""]
    if "load_average_start" in result:
        L += [f"Load average at start / end: {', '.join(f'{x:.2f}' for x in result['load_average_start'])} / "
              f"{', '.join(f'{x:.2f}' for x in result.get('load_average_end', []))} "
              f"on {result['cpu_count']} cores (other processes share the machine).", ""]
    L += ["## References", "",
          "| scene | reference | mutual relMSE of the two | mean's own relMSE (subtracted) | smallest measured relMSE | ok |",
          "|---|---|---|---|---|---|"]
    for name, info in result["scenes"].items():
        r = info["reference"]
        L.append(f"| {name} | {r['integrator']}, 2 × {r['spp']} spp | {r['mutual_rel_mse']:.2g} | "
                 f"{r['estimated_rel_mse_of_mean']:.2g} ± {r.get('own_rel_mse_error', 0.0):.1g} | "
                 f"{r['smallest_measured_rel_mse']:.3g} | "
                 f"{'yes' if r['ok'] else 'NO'} |")
    for name, info in result["scenes"].items():
        cc = info["reference"].get("cross_check")
        if cc:
            L += ["", f"{name}: a {cc['integrator']} reference ({cc['spp']} spp) against the "
                      f"{info['reference']['integrator']} one: image means within {cc['worst_mean_deviation']:.2%}, "
                      f"the {cc['regions_compared']} lit regions of a 4 × 4 grid within {cc['worst_region_deviation']:.2%} "
                      f"(relMSE {cc['rel_mse_vs_reference']:.3g}) → {'agree' if cc['agree'] else 'DISAGREE'} at 1 %."]
    L += ["", f"## Time to reach a relMSE, and relMSE at an equal time budget of {cfg['budget_seconds']:g} s", "",
          "| scene | series | slope | s to relMSE 1e-2 | s to relMSE 1e-3 | relMSE at "
          f"{cfg['budget_seconds']:g} s |", "|---|---|---|---|---|---|"]
    for name, info in result["scenes"].items():
        for label, s in info["series"].items():
            t2, t3, eb = s["time_to_0.01"], s["time_to_0.001"], s["rel_mse_at_budget"]
            L.append(f"| {name} | {label} | {s['fit']['slope']:.2f} | {fmt(t2)} ({t2['how'][:6]}.) | "
                     f"{fmt(t3)} ({t3['how'][:6]}.) | {fmt(eb)} ({eb['how'][:6]}.) |")
    L += ["", "## Ratios of times to equal error (same run, per repetition)", "",
          "A ratio below 1 means the first series is faster to the same error.", "",
          "| scene | ratio | at relMSE 1e-2 | at relMSE 1e-3 |", "|---|---|---|---|"]
    for name, info in result["scenes"].items():
        for key, r in info["ratios"].items():
            if "units_agree" in r and not r["units_agree"]:
                L.append(f"| {name} | {key} | not quoted: units disagree | |")
                continue
            L.append(f"| {name} | {key} | {fmt(r['0.01'])} ({r['0.01']['how'][:6]}.) | "
                     f"{fmt(r['0.001'])} ({r['0.001']['how'][:6]}.) |")
    peers = {n: i["peer"] for n, i in result["scenes"].items() if i.get("peer")}
    L += ["", "## Mitsuba 3 side by side: unit agreement first", ""]
    if result["peer"]:
        L += ["Variants: " + "; ".join(f"`{k}`: {v}" for k, v in result["peer"].items()), ""]
    if peers:
        L += ["| scene | peer | peer reference | image-mean ratio (R, G, B) | worst region | agree within 1 % |",
              "|---|---|---|---|---|---|"]
        for name, pi in peers.items():
            for tag, v in pi.items():
                if "error" in v:
                    L.append(f"| {name} | {tag} | not comparable: {v['error']} | | | |")
                    continue
                L.append(f"| {name} | {tag} | path, {v['reference_spp']} spp | "
                         f"{', '.join(f'{x:.4f}' for x in v['mean_ratio'])} | {v['worst_region_deviation']:.2%} "
                         f"({v['regions_compared']} regions) | {'yes' if v['agree'] else 'NO'} |")
    else:
        L.append("No peer in this run.")
    L += ["", "## Points (median ± half-range over repetitions)", "",
          "| scene | series | spp | seconds | relMSE | RMSE |", "|---|---|---|---|---|---|"]
    for name, info in result["scenes"].items():
        for label, s in info["series"].items():
            for r in s["rungs"]:
                L.append(f"| {name} | {label} | {r['spp']} | {fmt(r['seconds'])} | {fmt(r['rel_mse'])} | "
                         f"{fmt(r['rmse'])} |")
    return "\n".join(L) + "\n"


# -- command line ------------------------------------------------------------------------
