"""The `tessera` command: render locally, run a worker, or serve the farm's API."""
from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 640x480, not {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError("resolution must be positive")
    return w, h


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def cmd_render(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from tessera_renderer import NonFiniteSampleError, SceneError, load_scene

    from .images import render_metadata, write_exr, write_png_preview
    from .local import render_image
    from .protocol import RenderSettings

    scene_path = Path(args.scene)
    output = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    try:
        scene = load_scene(scene_path, frame=args.frame)
    except SceneError as exc:
        print(f"tessera render: {exc}", file=sys.stderr)
        return 2
    width, height = args.res or (scene.width, scene.height)
    try:
        settings = RenderSettings(width=width, height=height, spp=args.spp, seed=args.seed,
                                  max_depth=args.max_depth, tile_size=args.tile)
    except ValidationError as exc:
        print(f"tessera render: invalid settings: {exc}", file=sys.stderr)
        return 2
    for w in scene.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"{scene_path.name}: {scene.num_triangles} triangles, {scene.num_emitters} emitters; "
          f"{width}x{height}, {settings.spp} spp, seed {settings.seed}", file=sys.stderr)
    try:
        result = render_image(scene, settings, threads=args.threads, progress=not args.quiet)
    except NonFiniteSampleError as exc:
        print(f"tessera render: renderer bug: {exc}", file=sys.stderr)
        return 3
    output.parent.mkdir(parents=True, exist_ok=True)
    write_exr(output, result.rgba, render_metadata(settings.spp, settings.seed, scene_path.name))
    preview = output.with_suffix(".png")
    write_png_preview(preview, result.rgba)
    print(f"wrote {output} and {preview} in {result.seconds:.2f} s "
          f"({result.samples_per_second / 1e6:.2f} M samples/s)", file=sys.stderr)
    return 0


def cmd_worker(args: argparse.Namespace) -> int:
    from tessera_worker.worker import run_worker

    redis_url = args.redis_url or os.environ.get("REDIS_URL")
    if not redis_url:
        print("tessera worker: set REDIS_URL or pass --redis-url", file=sys.stderr)
        return 2
    run_worker(redis_url, name=args.name, threads=args.threads)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from tessera_service.embedded import serve

    serve(host=args.host, port=args.port, workers=args.workers,
          redis_url=args.redis_url or os.environ.get("REDIS_URL") or None,
          worker_threads=args.worker_threads)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tessera", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a USD scene locally to EXR + PNG preview")
    r.add_argument("scene", help=".usda/.usdc/.usdz file")
    r.add_argument("-o", "--output", help="output EXR (default: SCENE_NAME.exr here); the PNG goes beside it")
    r.add_argument("--spp", type=_positive, default=64, help="samples per pixel (default 64)")
    r.add_argument("--res", type=_resolution, help="WxH; default from the scene's RenderSettings, else 512x512")
    r.add_argument("--threads", type=int, default=0, help="render threads (default: all cores)")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.add_argument("--max-depth", type=_positive, default=64, help="maximum bounces (default 64)")
    r.add_argument("--tile", type=_positive, default=64, help="tile size in pixels (default 64)")
    r.add_argument("--frame", type=float, help="time code to render (default: the stage's default time)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_render)

    w = sub.add_parser("worker", help="render tiles from the Redis queue at REDIS_URL")
    w.add_argument("--redis-url", help="default: $REDIS_URL")
    w.add_argument("--name", help="consumer name (default: host-pid-random)")
    w.add_argument("--threads", type=int, default=0, help="render threads (default: all cores)")
    w.set_defaults(func=cmd_worker)

    s = sub.add_parser("serve", help="run the HTTP API; without REDIS_URL also a private Redis and local workers")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--workers", type=int, default=2, help="local workers in the embedded mode (default 2)")
    s.add_argument("--worker-threads", type=int, default=1, help="render threads per local worker (default 1)")
    s.add_argument("--redis-url", help="use this Redis instead of starting one (default: $REDIS_URL)")
    s.set_defaults(func=cmd_serve)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    return args.func(args)
