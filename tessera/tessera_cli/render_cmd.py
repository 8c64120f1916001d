"""`tessera render`: one image, or a numbered image per frame, rendered here."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tessera_base.settings_spec import RENDER

from .options import settings_error, settings_from_args, settings_problem

def cmd_render(args: argparse.Namespace) -> int:
    """One image, or with --frames one numbered image per frame (out.0001.exr, ...)."""
    if (problem := output_problem(args.output)) is not None:
        print(f"tessera render: {problem}", file=sys.stderr)
        return 2
    if not args.frames:
        return _render_one(args)
    from tessera_base.protocol import numbered_path, parse_frames

    try:
        frames = parse_frames(args.frames)
    except ValueError as exc:
        print(f"tessera render: --{exc}", file=sys.stderr)
        return 2
    output = args.output or Path(args.scene).stem + ".exr"
    for k, frame in enumerate(frames):
        print(f"frame {frame} ({k + 1} of {len(frames)})", file=sys.stderr)
        code = _render_one(argparse.Namespace(**{**vars(args), "frame": float(frame),
                                                 "output": numbered_path(output, frame),
                                                 "static_hint": k == 0 and len(frames) > 1}))
        if code:
            return code
    return 0


def output_problem(output: str | None) -> str | None:
    """Why -o cannot name the image (it is a float EXR with layers: a .png cannot hold
    them), asked before anything is rendered; None when it can."""
    if output is None or Path(output).suffix.lower() == ".exr":
        return None
    preview = Path(output).with_suffix(".png")
    return (f"-o {output}: the image is a float EXR with its layers, so its name must end in .exr "
            f"(`-o {Path(output).with_suffix('.exr')}` also writes the PNG preview {preview})")


def _render_one(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from tessera_renderer import NonFiniteSampleError, SceneError, load_scene
    from tessera_renderer.usd.dicing import Dicing

    from tessera_base.images import write_png_preview
    from tessera_base.protocol import RenderSettings

    from tessera.rendering import render_scene

    scene_path = Path(args.scene)
    output = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    if (problem := settings_problem(args, RENDER)) is not None:  # before the scene loads
        print(f"tessera render: {problem}", file=sys.stderr)
        return 2
    values = settings_from_args(args, RENDER)
    try:
        from tessera_base.protocol import parse_variant

        scene = load_scene(scene_path, frame=args.frame, root=_local_root(args),
                           default_light=values.get("default_light", True),
                           subdivision_level=args.subdivision_level, camera=args.camera,
                           shutter=args.shutter, variants=[parse_variant(v) for v in args.variants or ()],
                           dicing=Dicing.requested(values.get("dicing_rate"), values.get("dicing_max_level"),
                                                   values.get("dicing_memory"), args.res))
    except SceneError as exc:
        hint = ("; if that folder is yours, let assets resolve within it with --root DIR, "
                "or render without --sandbox"
                if "outside the bundle" in str(exc) and not args.root else "")
        print(f"tessera render: {exc}{hint}", file=sys.stderr)
        return 2
    if getattr(args, "static_hint", False) and not getattr(scene.data, "animated", True):
        print(f"warning: {scene_path.name} has no animation (no time samples): every frame of "
              f"--frames {args.frames} renders the same image", file=sys.stderr)
    width, height = args.res or (scene.width, scene.height)
    if args.crop is not None:
        from tessera_base.images import check_crop

        try:
            check_crop(args.crop, width, height)
        except ValueError as exc:
            print(f"tessera render: --crop: {exc}", file=sys.stderr)
            return 2
    try:
        settings = RenderSettings(width=width, height=height, **values)
    except ValidationError as exc:
        print(f"tessera render: {settings_error(exc)}", file=sys.stderr)
        return 2
    if settings.denoise:  # before rendering, not after an hour of it
        from tessera_base.denoise import unavailable_reason

        if (reason := unavailable_reason()) is not None:
            print(f"tessera render: --denoise: {reason}", file=sys.stderr)
            return 2
    from tessera_base import integrators

    try:  # the values of the integrator's own settings, which only the integrator can judge
        scene.check_integrator(settings.integrator, max_depth=settings.max_depth,
                               integrator_params=settings.integrator_params)
    except ValueError as exc:
        print(f"tessera render: invalid settings: {exc}", file=sys.stderr)
        return 2
    for w in [*scene.warnings, *integrators.scene_warnings(scene.resolve_integrator(settings.integrator),
                                                           curve_segments=scene.num_curve_segments,
                                                           linked_lights=scene.num_linked_lights,
                                                           media=scene.has_media)]:
        print(f"warning: {w}", file=sys.stderr)
    samples = (f"noise target {settings.target_error:.2%} ({settings.min_spp}-{settings.max_spp} spp)"
               if settings.adaptive else f"{settings.spp} spp")
    instanced = (f" ({scene.num_instances} instances, {scene.num_stored_triangles} triangles stored)"
                 if scene.num_instances else "")
    data = scene.data
    when = f"; time code {data.time_code:g}" if getattr(data, "time_code", None) is not None else ""
    if getattr(data, "shutter", None) is not None:
        when += (f", motion blur over [{data.shutter[0]:g}, {data.shutter[1]:g}] "
                 f"({len(data.motion_instances)} moving)")
    # Textures are held whole (no texture cache bounds them): their memory belongs in the log.
    textures = f", textures {scene.texture_bytes / 2**20:.0f} MB" if scene.texture_bytes else ""
    print(f"{scene_path.name}: {scene.num_triangles} triangles{instanced}, {scene.num_emitters} emitters{textures}; "
          f"{width}x{height}, {samples}, seed {settings.seed}{when}", file=sys.stderr)
    if getattr(data, "subdivision_summary", None):
        print(data.subdivision_summary, file=sys.stderr)
    try:
        image = render_scene(scene, settings, scene_name=scene_path.name, threads=args.threads,
                             progress=not args.quiet, variance=not args.no_variance,
                             log=lambda line: print(line, file=sys.stderr))
    except NonFiniteSampleError as exc:
        print(f"tessera render: renderer bug: {exc}", file=sys.stderr)
        return 3
    from tessera_base.exr_header import scene_sha256
    from tessera_base.protocol import in_crop

    image.metadata["tessera:scene_sha256"] = scene_sha256(scene_path)
    image.write(output, crop=args.crop)
    result = image.metadata
    preview = output.with_suffix(".png")
    write_png_preview(preview, in_crop(settings, image.rgba))  # a crop's preview is the crop
    if result.get("black_warning"):
        print(f"warning: {result['black_warning']}", file=sys.stderr)
    if result["denoise_warning"]:
        print(f"warning: {result['denoise_warning']}", file=sys.stderr)
    elif settings.denoise:
        denoised = output.with_name(output.stem + ".denoised.png")
        write_png_preview(denoised, in_crop(settings, image.layers["denoised"]))
        preview = f"{preview} ({denoised} denoised)"
    if settings.adaptive:
        mean_spp = result["samples"] / (settings.width * settings.height)
        print(f"noise target {settings.target_error:.2%}: {mean_spp:.1f} spp on average, "
              f"{result['passes']} tile passes", file=sys.stderr)
        if (missed := target_missed(result, settings.time_limit)) is not None:
            print(f"warning: {missed}", file=sys.stderr)
    print(f"wrote {output} and {preview} in {result['seconds']:.2f} s "
          f"({result['samples_per_second'] / 1e6:.2f} M samples/s)", file=sys.stderr)
    return 0


def target_missed(header: dict, time_limit: float | None = None) -> str | None:
    """What a noise-target render fell short by, from its EXR header (the image's measured
    noise, tessera:reached_error, against tessera:target_error); None when it got there or
    the image carries no noise estimate."""
    try:
        target = float(header["tessera:target_error"])
        reached = float(header["tessera:reached_error"])
    except (KeyError, TypeError, ValueError):
        return None
    if reached <= target:
        return None
    limit = f"--max-spp {header.get('tessera:spp', '?')}" + (f" or --time-limit {time_limit:g} s"
                                                             if time_limit else "")
    return (f"noise target {target:.2%} not reached: the image's noise is {reached:.2%}, "
            f"{reached / target:.1f}x the target (tessera:reached_error); stopped by {limit}")


def _local_root(args: argparse.Namespace) -> str:
    """Where a local render's assets may resolve: the user's own files are trusted (the
    whole filesystem, as usdview opens them) unless --sandbox or --root asks for the
    sandbox a farm upload gets (docs/scene-translation.md, "The bundle sandbox")."""
    if args.root:
        return args.root
    return str(Path(args.scene).absolute().parent) if args.sandbox else "/"
