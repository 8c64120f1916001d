"""What a crop saves: render time of a crop window against its share of the frame.

    .venv/bin/python benchmarks/crop.py [--reps 3] [--spp 8]

The Cornell box at 512x512, one scene load, then for each repetition every case in turn
(interleaved, so a busy neighbour slows all cases alike): the full frame and crops of 1/4
(`--crop 128,64,384,320`) and 1/16 of it with path (only the tiles meeting the crop are
rendered, cut to it: protocol.job_tiles) and with bdpt (every pixel's light subpath is
traced, since its splats may land in the crop, but outside the crop no camera subpath and
no strategy but the splats), the full frame and the 1/4 crop with vcm (as bdpt, and its
scene pass of shared light vertices stays whole) and with light (nothing to skip but one
camera ray a sample: the expected ratio is about 1). The scene load is outside the
timings. Writes docs/benchmarks/crop.md.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

from common import CORNELL, OUT, fmt, summary

QUARTER, SIXTEENTH = (128, 64, 384, 320), (192, 192, 320, 320)
CASES = [("path", None), ("path", QUARTER), ("path", SIXTEENTH),
         ("bdpt", None), ("bdpt", QUARTER), ("bdpt", SIXTEENTH),
         ("vcm", None), ("vcm", QUARTER),
         ("light", None), ("light", QUARTER)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--spp", type=int, default=8)
    args = ap.parse_args()
    from tessera.local import render_image
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    scene = load_scene(CORNELL)
    times: dict[tuple, list[float]] = {c: [] for c in CASES}
    for _ in range(args.reps):
        for integrator, crop in CASES:
            s = RenderSettings(width=512, height=512, spp=args.spp, integrator=integrator, crop=crop)
            started = time.perf_counter()
            render_image(scene, s, progress=False)
            times[(integrator, crop)].append(time.perf_counter() - started)
    lines = ["# Crop windows: time against area", "",
             f"`benchmarks/crop.py --reps {args.reps} --spp {args.spp}`: the Cornell box at 512x512, "
             f"{args.spp} spp, {os.cpu_count()} cores ({platform.processor() or platform.machine()}), "
             "cases interleaved in each repetition; median ± half-range over the repetitions. "
             "time / full: per repetition, the crop's time over the same integrator's full frame "
             "rendered in that repetition.", "",
             "| integrator | crop | area / full | time (s) | time / full |", "|---|---|---|---|---|"]
    for integrator, crop in CASES:
        t = summary(times[(integrator, crop)])
        area = 1.0 if crop is None else (crop[2] - crop[0]) * (crop[3] - crop[1]) / 512 ** 2
        # Paired by repetition: each crop against the full frame rendered beside it.
        ratios = summary([v / f for v, f in zip(times[(integrator, crop)], times[(integrator, None)])])
        lines.append(f"| {integrator} | {'full' if crop is None else ','.join(map(str, crop))} | "
                     f"{area:.4g} | {fmt(t, digits=3)} | {fmt(ratios, digits=3)} |")
    lines += ["", "path renders only the tiles meeting the crop, cut to it, so its time follows the "
              "area; what stays is the per-render overhead (tile set-up, image assembly over the "
              "full frame). The splatting integrators trace every pixel's light subpath, whose "
              "splats land in the crop too. Outside the crop bdpt and vcm skip the camera subpath "
              "and every strategy but those splats (t = 1), so their crop costs the light "
              "subpaths and their camera connections over the whole frame plus the full work of "
              "the crop's own pixels; vcm's scene pass (the shared light vertices) stays whole "
              "as well. light has only one camera ray a sample to skip: its crop costs about "
              "what its full frame costs (docs/aovs.md, \"Crop\")."]
    text = "\n".join(lines) + "\n"
    (OUT / "crop.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
