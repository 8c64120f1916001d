"""The `tessera` command: render locally, run a worker, or serve the farm's API."""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from pathlib import Path

from .dicing_options import add_dicing_options, dicing_from_args


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 640x480, not {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError("resolution must be positive")
    return w, h


def _crop(text: str) -> tuple[int, int, int, int]:
    try:
        x0, y0, x1, y1 = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"crop must look like X0,Y0,X1,Y1, not {text!r}") from None
    return x0, y0, x1, y1


def _int_range(low: int, high: int):
    """An argparse type: a whole number from low to high, refused in one line naming both."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be a whole number from {low} to {high}, not {text!r}")
        return value
    return parse


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


# The options that set each RenderSettings / job field, for messages in the user's terms.
_OPTIONS = {"width": "--res", "height": "--res", "tile_size": "--tile",
            "integrator_params": "--integrator-param", "variants": "--variant"}


def _option(field: str) -> str:
    return _OPTIONS.get(field, "--" + field.replace("_", "-"))


def _settings_error(exc, model=None) -> str:
    """A pydantic ValidationError of RenderSettings (or `model`) in one line: each problem
    as `--option: what is wrong (allowed values)`, without pydantic's own framing."""
    from tessera_base.protocol import RenderSettings

    model = model or RenderSettings
    parts = []
    for error in exc.errors(include_url=False):
        field = str(error["loc"][0]) if error.get("loc") else None
        message = error["msg"].removeprefix("Value error, ")
        ctx = error.get("ctx") or {}
        if field in model.model_fields and ({"ge", "gt", "le", "lt"} & set(ctx)):
            message = f"must be {_bounds(model.model_fields[field])}, not {error['input']!r}"
        if field is None:  # a check across fields: its message names them
            parts.append(message)
        else:
            parts.append(f"{_option(field)}: {message}")
    return "; ".join(dict.fromkeys(parts))


def _bounds(info) -> str:
    """A field's range as its Field(ge=..., le=...) declares it: `0-9`, `> 0 and <= 1`."""
    low = high = None
    for m in info.metadata:
        low = next((f"{op} {getattr(m, a)}" for a, op in (("ge", ">="), ("gt", ">")) if getattr(m, a, None) is not None), low)
        high = next((f"{op} {getattr(m, a)}" for a, op in (("le", "<="), ("lt", "<")) if getattr(m, a, None) is not None), high)
    if low and high and low.startswith(">=") and high.startswith("<="):
        return f"{low[3:]}-{high[3:]}"
    return " and ".join(b for b in (low, high) if b) or "valid"


def cmd_render(args: argparse.Namespace) -> int:
    """One image, or with --frames one numbered image per frame (out.0001.exr, ...)."""
    if (problem := _output_problem(args.output)) is not None:
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


def _output_problem(output: str | None) -> str | None:
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

    from tessera_base.images import write_png_preview
    from tessera_base.protocol import RenderSettings

    from tessera.rendering import render_scene

    scene_path = Path(args.scene)
    output = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    try:
        from tessera_base.protocol import parse_variant

        scene = load_scene(scene_path, frame=args.frame, root=_local_root(args),
                           default_light=not args.no_default_light,
                           subdivision_level=args.subdivision_level, camera=args.camera,
                           shutter=args.shutter, variants=[parse_variant(v) for v in args.variants or ()],
                           dicing=dicing_from_args(args))
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
    if (problem := _params_problem(args)) is not None:
        print(f"tessera render: {problem}", file=sys.stderr)
        return 2
    try:
        settings = RenderSettings(width=width, height=height, spp=args.spp, seed=args.seed,
                                  max_depth=args.max_depth, tile_size=args.tile,
                                  aovs=args.aovs or [], denoise=args.denoise, crop=args.crop, **_noise_target(args),
                                  integrator_params=_integrator_params(args),
                                  **({"integrator": args.integrator} if args.integrator else {}))
    except ValidationError as exc:
        print(f"tessera render: {_settings_error(exc)}", file=sys.stderr)
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
                                                           curve_segments=scene.num_curve_segments)]:
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
    print(f"{scene_path.name}: {scene.num_triangles} triangles{instanced}, {scene.num_emitters} emitters; "
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
        if (missed := _target_missed(result, settings.time_limit)) is not None:
            print(f"warning: {missed}", file=sys.stderr)
    print(f"wrote {output} and {preview} in {result['seconds']:.2f} s "
          f"({result['samples_per_second'] / 1e6:.2f} M samples/s)", file=sys.stderr)
    return 0


def _target_missed(header: dict, time_limit: float | None = None) -> str | None:
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


def _noise_target(args: argparse.Namespace) -> dict:
    """The noise-target settings of `render` (and `submit`); empty for a fixed spp."""
    if args.target_error is None:
        return {}
    return {k: v for k, v in dict(target_error=args.target_error, min_spp=args.min_spp,
                                  max_spp=args.max_spp, time_limit=args.time_limit).items()
            if v is not None}


class _IntegratorOption(argparse.Action):
    """--integrator NAME, checked against the renderer's registry before anything is
    loaded; `--integrator help` lists the integrators and exits. With `renders` (the
    command loads the renderer anyway) the registry is read in process, not from a child."""

    def __init__(self, *args, renders: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.renders = renders

    def __call__(self, parser, namespace, value, option_string=None):
        if self.renders:
            import tessera_renderer  # noqa: F401
        from tessera_base import integrators
        if value == "help":
            print(integrators.help_text())
            sys.stdout.flush()  # a closed pipe raises here, inside main's handler
            parser.exit(0)
        try:
            setattr(namespace, self.dest, integrators.validate(value))
        except ValueError as exc:
            parser.error(str(exc))


def _add_integrator_option(parser: argparse.ArgumentParser, renders: bool = False) -> None:
    parser.add_argument("--integrator", default=None, action=_IntegratorOption, renders=renders, metavar="NAME",
                        help="light transport method (default: the registry's first; `help` lists "
                             "them; see docs/integrators.md)")
    parser.add_argument("--integrator-param", dest="integrator_params", action="append", default=None,
                        type=_integrator_param, metavar="NAME=VALUE",
                        help="one of the integrator's own settings (repeatable; `--integrator help` "
                             "lists them), e.g. --integrator ao --integrator-param max_distance=2")


def _integrator_param(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), value.strip()


def _integrator_params(args: argparse.Namespace) -> dict[str, str]:
    """--integrator-param pairs as a dict (checked by RenderSettings against the registry)."""
    return dict(args.integrator_params or [])


def _add_aov_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--aovs", default=None, metavar="LIST",
                        help="extra EXR layers, comma-separated: albedo, normal, depth, spp, variance, "
                             "or all (default none; see docs/aovs.md)")


def _add_default_light_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-default-light", action="store_true",
                        help="a scene without any light renders black instead of getting the "
                             "default lighting (white dome + camera key light)")


def _add_subdivision_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--subdivision-level", type=int, choices=range(7), default=None, metavar="N",
                        help="times subdivision surfaces are refined, 0-6 (default 2; 0 renders "
                             "their control cage; see docs/scene-translation.md)")


def _add_camera_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--camera", default=None, metavar="PRIM_PATH",
                        help="the Camera prim to render through, e.g. /World/Cameras/closeup (default: "
                             "the RenderSettings' camera, else the first camera, else a three-quarter "
                             "view framing the scene; docs/scene-translation.md)")


def _variant(text: str) -> str:
    from tessera_base.protocol import parse_variant

    try:
        parse_variant(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _add_variant_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--variant", dest="variants", action="append", type=_variant, default=None,
                        metavar="PRIM:SET=VALUE",
                        help="render with this variant selected, e.g. /Car:color=red (repeatable; in place "
                             "of the stage's own selection; docs/scene-translation.md, \"Variants\")")


def _shutter(text: str) -> tuple[float, float]:
    try:
        open_, close = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected OPEN,CLOSE (two time codes), not {text!r}") from None
    if not (math.isfinite(open_) and math.isfinite(close)) or open_ > close:
        raise argparse.ArgumentTypeError(f"must be finite with OPEN <= CLOSE, not {text!r}")
    return open_, close


def _add_time_options(parser: argparse.ArgumentParser, frames: bool = False) -> None:
    group = parser.add_mutually_exclusive_group() if frames else parser
    group.add_argument("--frame", type=float, default=None, metavar="TIME",
                       help="the USD time code to render (default: the stage's startTimeCode, else "
                            "its default time; docs/motion.md)")
    if frames:
        group.add_argument("--frames", default=None, metavar="LIST",
                           help="render these frames, one EXR each: 1-24, 1-24x2 (every second), "
                                "1,5,9 or a mix; the output's run of # is the frame number "
                                "(default: OUTPUT with .#### before .exr: out.0001.exr); on a farm, "
                                "one job per frame")
    parser.add_argument("--shutter", type=_shutter, default=None, metavar="OPEN,CLOSE",
                        help="motion blur over [frame+OPEN, frame+CLOSE] in time codes, replacing the "
                             "camera's shutter:open/close; 0,0 renders without motion blur "
                             "(docs/motion.md)")


def _add_denoise_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--denoise", action="store_true",
                        help="add an Open Image Denoise layer (denoised.R/G/B) and a denoised PNG "
                             "preview; R, G, B stay the raw render; adds the albedo and normal "
                             "AOVs (docs/denoise.md)")


def _add_noise_target_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--target-error", type=float, nargs="?", const=0.01, default=None,
                        metavar="REL", help="render to a relative noise target instead of a "
                                            "fixed --spp (default target 0.01 = 1 %%)")
    parser.add_argument("--min-spp", type=_positive, help="noise target: first pass (default 16)")
    parser.add_argument("--max-spp", type=_positive, help="noise target: most samples (default 1024)")
    parser.add_argument("--time-limit", type=float,
                        help="noise target: seconds after which no further passes start")


def cmd_worker(args: argparse.Namespace) -> int:
    from tessera_worker.settings import settings_from_args
    from tessera_worker.worker import run_worker

    if not (args.redis_url or os.environ.get("REDIS_URL")
            or os.environ.get("TESSERA_WORKER_REDIS_URL")):
        print("tessera worker: set REDIS_URL or pass --redis-url", file=sys.stderr)
        return 2
    run_worker(settings=settings_from_args(args), name=args.name)
    return 0


def _submit_pilot(args: argparse.Namespace):
    """`submit --integrator auto`: the pilot (tessera.pilot) runs here, on the scene as the
    farm will load it (its bundle sandbox, frame, camera, variants), so that the job carries
    one measured choice that every worker renders, and its numbers."""
    from tessera_base.protocol import RenderSettings, parse_variant, parse_frames
    from tessera_renderer import load_scene

    from tessera.pilot import run_pilot

    frame = args.frame
    if frame is None and getattr(args, "frames", None):
        frame = float(parse_frames(args.frames)[0])
    scene = load_scene(Path(args.scene), frame=frame, default_light=not args.no_default_light,
                       subdivision_level=args.subdivision_level, camera=args.camera, shutter=args.shutter,
                       variants=[parse_variant(v) for v in args.variants or ()])
    width, height = args.res or (scene.width, scene.height)
    return run_pilot(scene, RenderSettings(width=width, height=height, max_depth=args.max_depth or 64))


def _submit_problem(args: argparse.Namespace) -> str | None:
    """What the farm would refuse in `submit`'s settings, found here before the scene is
    packed and uploaded (the resolution may be the scene's, unknown until the farm reads it:
    then only what does not depend on it); None when there is nothing."""
    from pydantic import ValidationError

    from tessera_base.protocol import RenderSettings, parse_frames

    if args.output and (problem := _output_problem(args.output)) is not None:
        return problem
    if args.frames:
        try:
            parse_frames(args.frames)
        except ValueError as exc:
            return f"--{exc}"
    if (problem := _params_problem(args)) is not None:
        return problem
    width, height = args.res or (16384, 16384)
    fields = dict(spp=args.spp, seed=args.seed, max_depth=args.max_depth, tile_size=args.tile,
                  integrator=args.integrator, subdivision_level=args.subdivision_level,
                  camera=args.camera, frame=args.frame, shutter=args.shutter, variants=args.variants,
                  crop=args.crop if args.res else None, aovs=args.aovs,
                  integrator_params=_integrator_params(args), **_noise_target(args))
    try:
        RenderSettings(width=width, height=height, **{k: v for k, v in fields.items() if v is not None})
    except ValidationError as exc:
        return _settings_error(exc)
    return None


def _params_problem(args: argparse.Namespace) -> str | None:
    """--integrator-param names the integrator does not take, in the option's terms."""
    from tessera_base import integrators

    try:
        integrators.validate_params(args.integrator or integrators.default(), _integrator_params(args))
    except ValueError as exc:
        return f"--integrator-param: {exc}"
    return None


def cmd_submit(args: argparse.Namespace) -> int:
    """Uploads a scene to a farm's API (through tessera.Client: a loose layer travels with
    its assets); with --wait follows its progress and downloads the image."""
    from tqdm import tqdm

    from tessera.client import Client, FarmError

    scene = Path(args.scene)
    settings = {k: v for k, v in dict(spp=args.spp, seed=args.seed, max_depth=args.max_depth,
                                      tile_size=args.tile, priority=args.priority, integrator=args.integrator,
                                      max_attempts=args.max_attempts,
                                      default_light="false" if args.no_default_light else None,
                                      denoise=args.denoise or None,
                                      subdivision_level=args.subdivision_level, camera=args.camera,
                                      frame=args.frame, shutter=args.shutter, frames=args.frames,
                                      variants=",".join(args.variants) if args.variants else None,
                                      crop=",".join(map(str, args.crop)) if args.crop else None,
                                      **_noise_target(args)).items() if v is not None}
    if (problem := _submit_problem(args)) is not None:  # before anything is packed or sent
        print(f"tessera submit: {problem}", file=sys.stderr)
        return 2
    report = lambda line: print(line, file=sys.stderr)  # noqa: E731
    try:
        with Client(args.server, args.token or os.environ.get("TESSERA_TOKEN")) as farm:
            if args.integrator == "auto":
                farm.health()  # a farm that cannot be reached is said before the pilot's seconds
                try:
                    pilot = _submit_pilot(args)
                except (OSError, ValueError) as exc:  # SceneError is a ValueError
                    print(f"tessera submit: --integrator auto: the pilot could not load the scene: {exc}",
                          file=sys.stderr)
                    return 2
                report(pilot.summary())
                settings.update(integrator=pilot.choice, auto_pilot=pilot.to_json())
            try:
                job = farm.submit(scene, res=args.res, aovs=args.aovs.split(",") if args.aovs else (),
                                  integrator_params=_integrator_params(args) or None,
                                  report=report, **settings)
            except FarmError as exc:
                if exc.status_code is None:
                    raise
                print(f"tessera submit: the server refused the job ({exc.status_code}): {exc.detail}",
                      file=sys.stderr)
                return 2
            except (OSError, ValueError, RuntimeError) as exc:  # a scene unreadable here, UploadError
                print(f"tessera submit: {exc}", file=sys.stderr)
                return 2
            for w in job.warnings:
                print(f"warning: {w}", file=sys.stderr)
            print(job.id)
            if not args.wait:
                return 0
            with tqdm(total=job.tiles_total, unit="tile", desc=job.id[:8], disable=args.quiet,
                      dynamic_ncols=True) as bar:
                finished = 0  # tiles of the frames already followed
                for frame_job in (job.frames or {job.id: job.id}).values():
                    for event in farm.events(frame_job):
                        if event.type == "tile" and event.tiles_done is not None:
                            bar.n = finished + event.tiles_done
                            bar.refresh()
                    finished += farm.status(frame_job).tiles_done
                status = farm.status(job.id)
                bar.n = status.tiles_done
                bar.refresh()
            if status.state != "done":
                failed = [f"frame {f['frame']} {f['state']}" + (f": {f['error']}" if f.get("error") else "")
                          for f in status.raw.get("frames") or [] if f["state"] != "done"]
                print(f"tessera submit: job {job.id} {status.state}"
                      + (f": {status.error}" if status.error else "")
                      + (f" ({'; '.join(failed)})" if failed else ""), file=sys.stderr)
                return 1
            output = Path(args.output) if args.output else Path(scene.stem + ".exr")
            try:
                if job.frames:
                    from tessera_base.protocol import numbered_path

                    images = {f: farm.download_frame(job.id, f, numbered_path(str(output), f)) for f in job.frames}
                    output = Path(numbered_path(str(output), next(iter(job.frames))))
                else:
                    images = {None: farm.download(job.id, output)}
                    # Found once the image is merged (a black image): not in the submit answer.
                    for w in farm.status(job.id).warnings:
                        if w not in job.warnings:
                            print(f"warning: {w}", file=sys.stderr)
            except FarmError as exc:
                if exc.status_code is None:
                    raise
                print(f"tessera submit: cannot download the image: {exc.detail}", file=sys.stderr)
                return 1
            if None in images and status.raw.get("reached_error") is not None:
                # The job's own verdict (GET /jobs/ID), known whether or not the EXR has a
                # noise layer.
                images[None].metadata.update({
                    "tessera:target_error": str(status.raw["settings"]["target_error"]),
                    "tessera:reached_error": str(status.raw["reached_error"]),
                    "tessera:spp": str(status.raw["settings"]["max_spp"])})
            for f, image in images.items():
                if (missed := _target_missed(image.metadata, args.time_limit)) is not None:
                    print(f"warning: {'' if f is None else f'frame {f}: '}{missed}", file=sys.stderr)
            many = f" and {len(job.frames) - 1} more frames" if job.frames and len(job.frames) > 1 else ""
            elapsed = f" ({status.elapsed_seconds:.2f} s on the farm)" if status.elapsed_seconds is not None else ""
            print(f"wrote {output}{many}{elapsed}", file=sys.stderr)
            return 0
    except FarmError as exc:
        print(f"tessera submit: {exc}", file=sys.stderr)
        return 2


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
                                   integrator_params={k: float(v) for k, v in _integrator_params(args).items()})
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
    r.add_argument("--spp", type=_positive, default=64, help="samples per pixel (default 64)")
    r.add_argument("--res", type=_resolution, help="WxH; default from the scene's RenderSettings, else 512x512")
    r.add_argument("--threads", type=int, default=0, help="render threads (default: all cores)")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.add_argument("--max-depth", type=_positive, default=64, help="maximum bounces (default 64)")
    r.add_argument("--tile", type=_positive, default=64, help="tile size in pixels (default 64)")
    r.add_argument("--root", help="with the sandbox: the folder every asset path must resolve within "
                                  "(implies --sandbox; default: the scene's folder)")
    r.add_argument("--sandbox", action="store_true",
                   help="read the scene as the farm reads an upload: every asset must resolve inside "
                        "the scene's folder (or --root), no absolute paths (default: trust the local "
                        "files, so references to ../ and absolute paths work)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    _add_noise_target_options(r)
    _add_integrator_option(r, renders=True)
    _add_aov_option(r)
    _add_default_light_option(r)
    _add_denoise_option(r)
    _add_subdivision_option(r)
    add_dicing_options(r)
    _add_camera_option(r)
    _add_variant_option(r)
    _add_time_options(r, frames=True)
    r.add_argument("--crop", type=_crop, default=None, metavar="X0,Y0,X1,Y1",
                   help="write only this pixel region (X1, Y1 exclusive) as the EXR's data "
                        "window, the full frame as its display window; only the region is "
                        "rendered (light, bdpt and vcm trace the whole frame: light paths from "
                        "anywhere land in it); the PNG preview is the region")
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
    m.add_argument("--spp", type=_positive, help="samples per pixel (server default 64)")
    m.add_argument("--res", type=_resolution, help="WxH (default: the scene's)")
    m.add_argument("--seed", type=int)
    m.add_argument("--max-depth", type=_positive)
    m.add_argument("--tile", type=_positive, help="tile size in pixels")
    from tessera_base.protocol import DEFAULT_PRIORITY, MAX_PRIORITY, MIN_PRIORITY

    m.add_argument("--priority", type=_int_range(MIN_PRIORITY, MAX_PRIORITY),
                   help=f"{MIN_PRIORITY}-{MAX_PRIORITY}, higher first (default {DEFAULT_PRIORITY})")
    m.add_argument("--max-attempts", type=_int_range(1, 100),
                   help="failed attempts at one tile before the job fails, 1-100 (default 3)")
    m.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    _add_default_light_option(m)
    _add_noise_target_options(m)
    _add_integrator_option(m)
    _add_aov_option(m)
    _add_denoise_option(m)
    _add_subdivision_option(m)
    _add_camera_option(m)
    _add_variant_option(m)
    _add_time_options(m, frames=True)
    m.add_argument("--crop", type=_crop, default=None, metavar="X0,Y0,X1,Y1",
                   help="the EXR holds only this region (X1, Y1 exclusive) as its data window")
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

    add_refs_parser(sub, _resolution, _positive, _add_integrator_option, _integrator_params)

    pv = sub.add_parser("preview", help="solve a scene's radiosity once and re-render it as the camera moves "
                                        "(a browser view on localhost; docs/integrators.md, radiosity)")
    pv.add_argument("scene", help=".usda/.usdc/.usdz file")
    pv.add_argument("--res", type=_resolution, default=(256, 256), help="WxH of the frames (default 256x256)")
    pv.add_argument("--threads", type=_positive, default=2, help="render threads (default 2)")
    pv.add_argument("--port", type=int, default=8765, help="localhost port of the view (default 8765; 0 takes a free one)")
    pv.add_argument("--frames", type=_positive, default=None,
                    help="no server: render N frames along an orbit and print the frame rate")
    pv.add_argument("--integrator-param", dest="integrator_params", action="append", default=None,
                    type=_integrator_param, metavar="NAME=VALUE",
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
