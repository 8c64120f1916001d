"""`tessera submit`: send a scene to a farm, follow its job, download the image."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from tessera_base.settings_spec import SUBMIT

from .options import settings_from_args, settings_problem
from .render_cmd import output_problem, target_missed

def _submit_pilot(args: argparse.Namespace):
    """`submit --integrator auto`: the pilot (tessera.pilot) runs here, on the scene as the
    farm will load it (its bundle sandbox, frame, camera, variants), so that the job carries
    one measured choice that every worker renders, and its numbers."""
    from tessera_base.protocol import RenderSettings, parse_variant, parse_frames
    from tessera_renderer import load_scene
    from tessera_renderer.usd.dicing import Dicing

    from tessera.pilot import run_pilot

    frame = args.frame
    if frame is None and getattr(args, "frames", None):
        frame = float(parse_frames(args.frames)[0])
    scene = load_scene(Path(args.scene), frame=frame, default_light=args.default_light is not False,
                       subdivision_level=args.subdivision_level, camera=args.camera, shutter=args.shutter,
                       variants=[parse_variant(v) for v in args.variants or ()],
                       dicing=Dicing.requested(args.dicing_rate, args.dicing_max_level, args.dicing_memory,
                                               args.res))
    width, height = args.res or (scene.width, scene.height)
    return run_pilot(scene, RenderSettings(width=width, height=height, max_depth=args.max_depth or 64))


def _submit_problem(args: argparse.Namespace) -> str | None:
    """What the farm would refuse in `submit`'s settings, found here before the scene is
    packed and uploaded; None when there is nothing."""
    from tessera_base.protocol import parse_frames

    if args.output and (problem := output_problem(args.output)) is not None:
        return problem
    if args.frames:
        try:
            parse_frames(args.frames)
        except ValueError as exc:
            return f"--{exc}"
    return settings_problem(args, SUBMIT)


def cmd_submit(args: argparse.Namespace) -> int:
    """Uploads a scene to a farm's API (through tessera.Client: a loose layer travels with
    its assets); with --wait follows its progress and downloads the image."""
    from tqdm import tqdm

    from tessera.client import Client, FarmError

    scene = Path(args.scene)
    values = settings_from_args(args, SUBMIT)
    integrator_params = values.pop("integrator_params", None)
    aovs = values.pop("aovs", None)
    settings = {k: v for k, v in dict(values, priority=args.priority, max_attempts=args.max_attempts,
                                      frames=args.frames).items() if v is not None}
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
                job = farm.submit(scene, res=args.res, aovs=aovs.split(",") if aovs else (),
                                  integrator_params=integrator_params,
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
                if (missed := target_missed(image.metadata, args.time_limit)) is not None:
                    print(f"warning: {'' if f is None else f'frame {f}: '}{missed}", file=sys.stderr)
            many = f" and {len(job.frames) - 1} more frames" if job.frames and len(job.frames) > 1 else ""
            elapsed = f" ({status.elapsed_seconds:.2f} s on the farm)" if status.elapsed_seconds is not None else ""
            print(f"wrote {output}{many}{elapsed}", file=sys.stderr)
            return 0
    except FarmError as exc:
        print(f"tessera submit: {exc}", file=sys.stderr)
        return 2
