"""The `tessera` command: render locally, run a worker, or serve the farm's API. Each
command's code is its own module (render_cmd, submit_cmd); the render settings' options
are generated from their declaration (options.add_setting_options)."""
from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from tessera_base.settings_spec import RENDER, SUBMIT

from .options import (add_frame_options, add_integrator_option, add_setting_options, int_range,
                      integrator_param, integrator_params, positive, resolution)
from .render_cmd import cmd_render
from .submit_cmd import cmd_submit

def cmd_worker(args: argparse.Namespace) -> int:
    from tessera_worker.settings import settings_from_args
    from tessera_worker.worker import run_worker

    if not (args.redis_url or os.environ.get("REDIS_URL")
            or os.environ.get("TESSERA_WORKER_REDIS_URL")):
        print("tessera worker: set REDIS_URL or pass --redis-url", file=sys.stderr)
        return 2
    run_worker(settings=settings_from_args(args), name=args.name)
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Exit 0: TEST and REFERENCE agree within their noise; 1: they differ; 2: usage error."""
    from tessera_tools.compare import CompareError, heatmap
    from tessera_base.images import write_png

    from tessera.comparison import comparison as compare_images

    try:
        comparison = compare_images(args.test, args.reference, alpha=args.alpha, method=args.method,
                                    flip=not args.no_flip, pooled=args.pooled)
    except CompareError as exc:
        print(f"tessera compare: {exc}", file=sys.stderr)
        return 2
    report = comparison.report
    print(report.summary())
    try:
        if args.report:
            Path(args.report).parent.mkdir(parents=True, exist_ok=True)
            Path(args.report).write_text(report.model_dump_json(indent=2) + "\n")
        heatmap_path = Path(args.heatmap) if args.heatmap else Path(args.test).with_suffix(".compare.png")
        heatmap_path.parent.mkdir(parents=True, exist_ok=True)
        write_png(heatmap_path, heatmap(comparison))
    except OSError as exc:
        print(f"tessera compare: {exc}", file=sys.stderr)
        return 2
    print(f"heatmap: {heatmap_path}" + (f", report: {args.report}" if args.report else ""), file=sys.stderr)
    return 1 if report.differs else 0


def cmd_denoise(args: argparse.Namespace) -> int:
    """Adds the denoised layer to an EXR that has the albedo and normal AOVs (one written by
    `tessera render --aovs albedo,normal`, say), as `render --denoise` would have."""
    from tessera_base.denoise import DENOISED_LAYER, DenoiseError, denoise
    from tessera_base.images import read_exr_aovs, read_render, write_exr, write_png_preview

    source = Path(args.image)
    output = Path(args.output) if args.output else source.with_name(source.stem + ".denoised.exr")
    try:
        image = read_render(source)
        layers = read_exr_aovs(source)
        layers[DENOISED_LAYER] = denoise(image.rgba, layers)
    except (OSError, ValueError, DenoiseError) as exc:
        print(f"tessera denoise: {source}: {exc}", file=sys.stderr)
        return 2
    metadata = {k: v for k, v in image.metadata.items() if k.startswith("tessera:")}
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_exr(output, image.rgba, metadata, aovs=layers)
        preview = output.with_suffix(".png")
        write_png_preview(preview, layers[DENOISED_LAYER])
    except OSError as exc:
        print(f"tessera denoise: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {output} (with {DENOISED_LAYER}.R/G/B) and {preview}", file=sys.stderr)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from tessera_cli.embedded import serve

    serve(host=args.host, port=args.port, workers=args.workers,
          redis_url=args.redis_url or os.environ.get("REDIS_URL") or None,
          worker_threads=args.worker_threads, insecure_local=args.insecure_local)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from tessera_tools.bench import main as bench_main

    return bench_main(args)


def cmd_preview(args: argparse.Namespace) -> int:
    """Solve a scene's radiosity once, then re-render it as the camera moves (tessera/preview.py)."""
    from tessera_renderer import SceneError, load_scene

    from tessera.preview import RadiosityPreview, serve
    width, height = args.res
    try:
        scene = load_scene(args.scene)
        preview = RadiosityPreview(scene, width=width, height=height, threads=args.threads,
                                   integrator_params={k: float(v) for k, v in integrator_params(args).items()})
    except (SceneError, ValueError, OSError) as exc:
        print(f"tessera preview: {exc}", file=sys.stderr)
        return 2
    print(f"solved in {preview.solve_seconds:.2f} s ({len(preview.product)} bytes)")
    if args.frames:
        b = preview.benchmark(args.frames)
        print(f"{b['frames']} frames of {width}x{height} on {args.threads} threads in {b['seconds']:.2f} s: "
              f"{b['fps']:.1f} frames/s")
        return 0
    serve(preview, port=args.port)
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse's errors in one line, naming the option (`tessera submit: argument
    --priority: must be 0-9 ...`), without the usage block the long commands print."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (`{self.prog} --help` lists the options)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tessera", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a USD scene locally to EXR + PNG preview")
    r.add_argument("scene", help=".usda/.usdc/.usdz file")
    r.add_argument("-o", "--output", help="output EXR (default: SCENE_NAME.exr here); the PNG goes beside it")
    r.add_argument("--res", type=resolution, help="WxH; default from the scene's RenderSettings, else 512x512")
    r.add_argument("--threads", type=int, default=0, help="render threads (default: all cores)")
    r.add_argument("--root", help="with the sandbox: the folder every asset path must resolve within "
                                  "(implies --sandbox; default: the scene's folder)")
    r.add_argument("--sandbox", action="store_true",
                   help="read the scene as the farm reads an upload: every asset must resolve inside "
                        "the scene's folder (or --root), no absolute paths (default: trust the local "
                        "files, so references to ../ and absolute paths work)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_setting_options(r, RENDER)
    add_integrator_option(r, renders=True)
    add_frame_options(r)
    r.add_argument("--no-variance", action="store_true",
                   help="write no variance and spp layers (a smaller EXR that `tessera compare` "
                        "cannot judge); it saves little time: the noise estimate comes from the "
                        "render's own samples, 1-7 %% of the time for light, bdpt and vcm "
                        "(docs/benchmarks/variance-batches.md)")
    r.set_defaults(func=cmd_render)

    from tessera_worker.settings import add_worker_options

    w = sub.add_parser("worker", help="render tiles from the Redis queue at REDIS_URL")
    add_worker_options(w)
    w.set_defaults(func=cmd_worker)

    m = sub.add_parser("submit", help="send a scene to a farm's API (see `tessera serve`)")
    m.add_argument("scene", help=".usda/.usdc/.usd file, packed with the layers and textures it "
                                 "references (only files the farm lacks are uploaded); or a "
                                 ".usdz/.zip bundle, sent as it is")
    m.add_argument("--server", default=os.environ.get("TESSERA_SERVER", "http://127.0.0.1:8000"),
                   help="API base URL (default: $TESSERA_SERVER or http://127.0.0.1:8000)")
    m.add_argument("--token", help="bearer token (default: $TESSERA_TOKEN)")
    m.add_argument("--wait", action="store_true",
                   help="follow the job with a progress bar and download the image")
    m.add_argument("-o", "--output", help="with --wait: the EXR to write (default: SCENE_NAME.exr here)")
    m.add_argument("--res", type=resolution, help="WxH (default: the scene's)")
    from tessera_base.protocol import DEFAULT_PRIORITY, MAX_PRIORITY, MIN_PRIORITY

    m.add_argument("--priority", type=int_range(MIN_PRIORITY, MAX_PRIORITY),
                   help=f"{MIN_PRIORITY}-{MAX_PRIORITY}, higher first (default {DEFAULT_PRIORITY})")
    m.add_argument("--max-attempts", type=int_range(1, 100),
                   help="failed attempts at one tile before the job fails, 1-100 (default 3)")
    m.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_setting_options(m, SUBMIT)
    add_integrator_option(m)
    add_frame_options(m)
    m.set_defaults(func=cmd_submit)

    c = sub.add_parser("compare", help="do two renders differ beyond their noise? "
                                       "(exit 0 same, 1 differs, 2 usage error)",
                       description="Per-pixel Welch t-tests (and 4x4, 16x16 and whole-image "
                                   "blocks) between two EXRs written by `tessera render`, which "
                                   "carry per-pixel variance; see docs/accuracy.md.")
    c.add_argument("test", help="EXR to check")
    c.add_argument("reference", help="EXR to check against")
    c.add_argument("--alpha", type=float, default=0.01,
                   help="false-alarm rate when both renderers agree (default 0.01)")
    c.add_argument("--method", choices=("bh", "bonferroni"), default="bh",
                   help="multiple-comparison correction: Benjamini-Hochberg (default) or Bonferroni")
    c.add_argument("--report", help="write the JSON report here")
    c.add_argument("--heatmap", help="difference heatmap PNG (default: TEST with .compare.png)")
    c.add_argument("--no-flip", action="store_true", help="skip the FLIP metric")
    c.add_argument("--pooled", action="store_true",
                   help="one per-sample variance pooled from both images (use when their spp "
                        "differ a lot, e.g. a cheap render against a costly reference: "
                        "Welch's t is biased there; docs/accuracy.md)")
    c.set_defaults(func=cmd_compare)

    d = sub.add_parser("denoise", help="add a denoised layer to an EXR with albedo and normal AOVs "
                                       "(docs/denoise.md)")
    d.add_argument("image", help="EXR written by tessera render with the albedo and normal AOVs")
    d.add_argument("-o", "--output", help="EXR to write: the image's layers plus denoised.R/G/B "
                                          "(default: IMAGE_NAME.denoised.exr beside it); the "
                                          "denoised PNG goes beside it")
    d.set_defaults(func=cmd_denoise)

    s = sub.add_parser("serve", help="run the HTTP API; without REDIS_URL also a private Redis and local workers")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--workers", type=int, default=2, help="local workers in the embedded mode (default 2)")
    s.add_argument("--worker-threads", type=int, default=1, help="render threads per local worker (default 1)")
    s.add_argument("--redis-url", help="use this Redis instead of starting one (default: $REDIS_URL)")
    s.add_argument("--insecure-local", action=argparse.BooleanOptionalAction, default=None,
                   help="without TESSERA_API_TOKENS, serve requests from this machine without a "
                        "token (default: yes for the embedded farm on 127.0.0.1, no with a "
                        "Redis URL)")
    s.set_defaults(func=cmd_serve)

    from tessera_tools.bench import add_options as add_bench_options

    b = sub.add_parser("bench", help="error versus time per integrator (and Mitsuba 3 side by side): "
                                     "CSV, plots and a summary (docs/benchmarks/error-vs-time.md)")
    add_bench_options(b)
    b.set_defaults(func=cmd_bench)

    from tessera.refs_cli import add_parser as add_refs_parser

    add_refs_parser(sub, resolution, positive, add_integrator_option, integrator_params)

    pv = sub.add_parser("preview", help="solve a scene's radiosity once and re-render it as the camera moves "
                                        "(a browser view on localhost; docs/integrators.md, radiosity)")
    pv.add_argument("scene", help=".usda/.usdc/.usdz file")
    pv.add_argument("--res", type=resolution, default=(256, 256), help="WxH of the frames (default 256x256)")
    pv.add_argument("--threads", type=positive, default=2, help="render threads (default 2)")
    pv.add_argument("--port", type=int, default=8765, help="localhost port of the view (default 8765; 0 takes a free one)")
    pv.add_argument("--frames", type=positive, default=None,
                    help="no server: render N frames along an orbit and print the frame rate")
    pv.add_argument("--integrator-param", dest="integrator_params", action="append", default=None,
                    type=integrator_param, metavar="NAME=VALUE",
                    help="a radiosity setting (`tessera render --integrator help` lists them)")
    pv.set_defaults(func=cmd_preview)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(asctime)s %(name)s %(levelname)s %(message)s")
        code = args.func(args)
        sys.stdout.flush()  # here, where a closed pipe can still be caught
        return code
    except BrokenPipeError:
        # The reader went away (`tessera render --integrator help | head`): what it read is
        # all it wanted. Point stdout at /dev/null so the interpreter's final flush is quiet.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
